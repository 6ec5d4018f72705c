#include "partloc/core/register_scan.hpp"

#include <algorithm>
#include <cmath>
#include <optional>

#include "partloc/core/format.hpp"
#include "partloc/core/scale_fit.hpp"

namespace partloc {

namespace {

std::string names_of(const std::vector<PlacedFiducial>& fiducials, const std::vector<std::size_t>& ks) {
    std::string n;
    for (std::size_t k : ks) n += (n.empty() ? "" : " and ") + fiducials[k].name;
    return n;
}

/// Where fiducial k's centre lies in the machine frame.
Eigen::Vector3d centre_of(const PlacedFiducial& f) { return f.T_machine_fiducial * f.model->dense.center; }

/// How far moving the scanner by D moves point c.
double shift_at(const Eigen::Isometry3d& D, const Eigen::Vector3d& c) { return (D * c - c).norm(); }

/// Everything the search of one scan keeps while it runs.
struct Search {
    const PreparedScan& scan;
    const std::vector<PlacedFiducial>& fiducials;
    const LocalizeSettings& localize;
    const RegistrationSettings& settings;
    std::vector<const PreparedModel*> models;
    std::vector<Eigen::Isometry3d> poses;
    double sampling = 0.0;
    std::vector<std::vector<FiducialFit>> candidates;  ///< each fiducial's own fits, where searched
    std::vector<char> searched;
    std::vector<Hypothesis> hyps;
    std::optional<Surface> all_target;  ///< every fiducial at its pose: one target for all the starts

    Search(const PreparedScan& s, const std::vector<PlacedFiducial>& f, const LocalizeSettings& l,
           const RegistrationSettings& r)
        : scan(s), fiducials(f), localize(l), settings(r), candidates(f.size()), searched(f.size(), 0) {
        for (const auto& p : f) {
            models.push_back(p.model);
            poses.push_back(p.T_machine_fiducial);
        }
        sampling = f.front().model->sampling;
    }

    /// Fiducials ks's global and fine fits, and a hypothesis from each of their candidates that passed.
    void run(const std::vector<std::size_t>& ks) {
        std::vector<const PpfModel*> tables;
        for (std::size_t k : ks) tables.push_back(models[k]->ppf.get());
        const auto global = ppf_detect(tables, scan.coarse_points, scan.coarse_normals);
        for (std::size_t j = 0; j < ks.size(); ++j) {
            const std::size_t k = ks[j];
            searched[k] = 1;
            candidates[k] = fit_candidates(scan, *models[k], localize, global[j]);
            for (const auto& c : candidates[k])
                if (c.valid) hyps.push_back(hypothesis_from(k, c));
        }
    }

    Hypothesis hypothesis_from(std::size_t k, const FiducialFit& c) {
        Hypothesis h;
        h.source_fit = c;
        h.source = k;
        h.T_machine_scan_initial = poses[k] * c.T_scan_fiducial.inverse();
        // Refined on every fiducial at once before the others are judged: one fiducial seen with a weakly
        // held direction can be off by tenths of a millimetre, enough to make the scan seem to contradict
        // another fiducial that is really there. If the refinement loses the source fiducial itself
        // (another one, moved, pulled it away), it is judged where its source put it.
        bool judged = false;
        if (models.size() > 1) {
            if (!all_target) all_target.emplace(make_pose_target(models, poses));
            const ScanPoseFit joint =
                fit_scan_pose(scan, models, poses, h.T_machine_scan_initial, localize,
                              settings.refine_start * sampling, &*all_target, settings.hypothesis_points);
            if (joint.valid && pose_error(joint.T_machine_scan, h.T_machine_scan_initial).translation <
                                   settings.refine_max_move * sampling)
                judged = judge_hypothesis(h, joint.T_machine_scan, scan, fiducials, localize, settings);
        }
        if (!judged) judge_hypothesis(h, h.T_machine_scan_initial, scan, fiducials, localize, settings);
        return h;
    }

    /// The fiducials are searched one at a time, in their order, until a hypothesis settles the scan: the
    /// searches not yet made could then only add hypotheses of the same placement, or lone ones that do not
    /// outweigh it.
    void all() {
        run({0});
        const std::size_t M = fiducials.size();
        if (settings.search_every_fiducial) {
            std::vector<std::size_t> rest;  // together, in one pass over the scan's pairs
            for (std::size_t k = 1; k < M; ++k) rest.push_back(k);
            if (!rest.empty()) run(rest);
            return;
        }
        const auto settled = [&](const Hypothesis& h) { return settles(h, searched, localize, settings); };
        for (std::size_t k = 1; k < M && !std::any_of(hyps.begin(), hyps.end(), settled); ++k) run({k});
    }

    /// Each fiducial's best fit, or how the winner judged it where it was not searched.
    std::vector<FiducialFit> fits(const Hypothesis* top) const {
        std::vector<FiducialFit> out;
        for (std::size_t k = 0; k < fiducials.size(); ++k) {
            if (!searched[k]) {
                // Not searched only when a hypothesis settled the scan; that one is corroborated and not
                // refuted, so there is a winner.
                out.push_back(top->judged[k]);
                out.back().searched = false;
            } else if (candidates[k].empty()) {
                FiducialFit none;
                none.fiducial = models[k]->name;
                none.reason = "no candidate pose: nothing in the scan is shaped like this fiducial";
                out.push_back(none);
            } else {
                out.push_back(candidates[k].front());
            }
        }
        return out;
    }

    /// Fiducials ks's models and poses.
    void subset(const std::vector<std::size_t>& ks, std::vector<const PreparedModel*>& ms,
                std::vector<Eigen::Isometry3d>& ps) const {
        for (std::size_t k : ks) {
            ms.push_back(models[k]);
            ps.push_back(poses[k]);
        }
    }

    ScanPoseFit joint_fit(const std::vector<std::size_t>& ks, const Eigen::Isometry3d& init) const {
        std::vector<const PreparedModel*> ms;
        std::vector<Eigen::Isometry3d> ps;
        subset(ks, ms, ps);
        const bool all = ks.size() == models.size() && all_target;  // ks keeps the fiducials' order
        return fit_scan_pose(scan, ms, ps, init, localize, 0.0, all ? &*all_target : nullptr);
    }

    /// How far fiducial k's own fit, started at T, moves the scan: at the fiducial, and in rotation; only the
    /// fiducials whose own fit moves it more than the noise explains.
    struct Disagreement {
        std::size_t k;
        double shift, turn_deg;
    };
    std::vector<Disagreement> disagreements(const std::vector<std::size_t>& in_view,
                                            const Eigen::Isometry3d& T) const {
        const double noise = scan.scale.noise;
        std::vector<Disagreement> out;
        for (std::size_t k : in_view) {
            const PreparedModel& m = *models[k];
            const ScanPoseFit own =
                fit_scan_pose(scan, {&m}, {poses[k]}, T, localize, settings.own_fit_start * m.sampling,
                              nullptr, settings.hypothesis_points);
            if (!own.valid) continue;
            const Eigen::Isometry3d D = own.T_machine_scan * T.inverse();
            const double shift = shift_at(D, centre_of(fiducials[k])), turn = rotation_angle_deg(D.linear());
            const double turn_tol = settings.own_fit_noise * noise / (0.5 * m.dense.diameter) * 180.0 / M_PI;
            if (shift > settings.own_fit_noise * noise || turn > turn_tol) out.push_back({k, shift, turn});
        }
        return out;
    }
};

}  // namespace

bool judge_hypothesis(Hypothesis& h, const Eigen::Isometry3d& T_machine_scan, const PreparedScan& scan,
                      const std::vector<PlacedFiducial>& fiducials, const LocalizeSettings& localize,
                      const RegistrationSettings& settings) {
    h.T_machine_scan = T_machine_scan;
    h.support = 0.0;
    h.explained.clear();
    h.contradicted.clear();
    h.judged.clear();
    bool source_ok = false;
    for (std::size_t g = 0; g < fiducials.size(); ++g) {
        const FiducialFit& e = h.judged.emplace_back(evaluate_model(
            scan, *fiducials[g].model, T_machine_scan.inverse() * fiducials[g].T_machine_fiducial, localize));
        if (e.seen_through >= settings.contradiction_bins &&
            e.violation > settings.contradiction_violation * localize.max_violation) {
            h.contradicted.push_back(g);
        } else if (e.valid) {
            h.support += support(e);
            h.explained.push_back(g);
            source_ok = source_ok || g == h.source;
        }
    }
    return source_ok;
}

bool settles(const Hypothesis& h, const std::vector<char>& searched, const LocalizeSettings& localize,
             const RegistrationSettings& settings) {
    if (!h.contradicted.empty() || h.explained.size() < 2) return false;
    for (std::size_t g = 0; g < h.judged.size(); ++g) {
        const FiducialFit& e = h.judged[g];
        if (!searched[g] && !e.valid &&
            (e.inliers >= localize.min_inliers || e.seen_through >= settings.contradiction_bins))
            return false;
    }
    return true;
}

void corroborate_and_refute(std::vector<Hypothesis>& hyps, const std::vector<PlacedFiducial>& fiducials,
                            const RegistrationSettings& settings) {
    // Two fiducials whose own fits put the scanner at about the same place corroborate each other: a
    // look-alike rarely has a second look-alike in the right place beside it. Where such a hypothesis
    // contradicts a third fiducial (or one of them, slightly), that fiducial has moved or was probed wrong.
    const double sampling = fiducials.front().model->sampling;
    for (auto& h : hyps)
        for (const auto& o : hyps) {
            if (o.source == h.source) continue;
            const Eigen::Isometry3d D = o.T_machine_scan_initial * h.T_machine_scan_initial.inverse();
            if (rotation_angle_deg(D.linear()) < settings.corroboration_deg &&
                shift_at(D, centre_of(fiducials[h.source])) < settings.corroboration_distance * sampling)
                ++h.corroborated;
        }
    for (auto& h : hyps) {
        if (h.explained.size() >= 2) h.corroborated = std::max<int>(h.corroborated, 1);
        const std::string& source = fiducials[h.source].name;
        if (!h.contradicted.empty() && h.corroborated == 0) {
            h.refuted = "with " + source + " as found, the scan contradicts " +
                        fiducials[h.contradicted.front()].name +
                        " where its probed pose puts it (a look-alike, or it moved or was probed wrong)";
        } else if (h.explained.empty()) {
            h.refuted = "with " + source + " as found, no fiducial passes its checks";
        }
    }
}

const Hypothesis* best_hypothesis(const std::vector<Hypothesis>& hyps) {
    const Hypothesis* top = nullptr;
    for (const auto& h : hyps) {
        if (!h.refuted.empty()) continue;
        if (!top || (h.corroborated > 0) > (top->corroborated > 0) ||
            ((h.corroborated > 0) == (top->corroborated > 0) && h.support > top->support))
            top = &h;
    }
    return top;
}

std::string rival_reason(const Hypothesis& top, const std::vector<Hypothesis>& hyps,
                         const std::vector<PlacedFiducial>& fiducials, double noise,
                         const LocalizeSettings& localize, const RegistrationSettings& settings) {
    const double sampling = fiducials.front().model->sampling;
    const Eigen::Vector3d c = centre_of(fiducials[top.source]);
    for (const auto& h : hyps) {
        if (&h == &top || !h.refuted.empty()) continue;
        if (top.corroborated > 0 && h.corroborated == 0) continue;  // a lone fit does not outweigh two
        const PoseError e = pose_error(h.T_machine_scan, top.T_machine_scan);
        if ((e.rotation_deg > settings.distinct_deg ||
             e.translation > settings.distinct_distance * sampling) &&
            h.support >= localize.ambiguity * top.support)
            return "ambiguous: two placements of the scanner explain the scan about equally well" +
                   format(" (%.3g deg, %.3g apart)", e.rotation_deg, e.translation);
        // Two sets of fiducials, each agreeing within itself, that put the scanner apart by more than the
        // noise explains: a fiducial that one set has and the other lacks moved or was probed wrong, and
        // this scan cannot tell which.
        if (h.corroborated > 0 && h.explained != top.explained) {
            const double apart = shift_at(h.T_machine_scan * top.T_machine_scan.inverse(), c);
            if (apart > settings.disagreement_noise * noise) {
                std::vector<std::size_t> differ;
                for (std::size_t g = 0; g < fiducials.size(); ++g) {
                    const bool a = std::count(top.explained.begin(), top.explained.end(), g) > 0;
                    const bool b = std::count(h.explained.begin(), h.explained.end(), g) > 0;
                    if (a != b) differ.push_back(g);
                }
                return "fiducials " + names_of(fiducials, differ) + format(" disagree by %.3g here", apart) +
                       ": one of them moved or was probed wrong";
            }
        }
    }
    // A scanner pose that one fiducial's fit alone supports is trusted only when no other fit that passed its
    // own checks, refuted or not, puts the scanner elsewhere with a fair share of its support: a
    // near-symmetric block, or a shape close to a fiducial's mirror image, fits in more than one way, and a
    // look-alike of one fiducial can hide where another is.
    if (top.corroborated == 0) {
        const double own = support(top.source_fit);
        for (const auto& h : hyps) {
            if (&h == &top || support(h.source_fit) < settings.rival_support * own) continue;
            const Eigen::Isometry3d D = h.T_machine_scan_initial * top.T_machine_scan_initial.inverse();
            const double turn = rotation_angle_deg(D.linear()), apart = shift_at(D, c);
            if (turn > settings.distinct_deg || apart > settings.distinct_distance * sampling)
                return "ambiguous: " + fiducials[top.source].name + " alone puts the scanner here, and " +
                       fiducials[h.source].name + "'s fit, which passes its own checks, puts it elsewhere" +
                       format(" (%.3g deg, %.3g apart)", turn, apart);
        }
    }
    if (!top.contradicted.empty() && top.explained.size() < 2) {
        // One fiducial against another: this scan cannot tell which of the two moved.
        std::vector<std::size_t> both = {top.source};
        both.insert(both.end(), top.contradicted.begin(), top.contradicted.end());
        return "fiducials " + names_of(fiducials, both) +
               " disagree here: one of them moved or was probed wrong (see the other scans)";
    }
    return "";
}

std::string symmetry_reason(const std::vector<std::size_t>& placing,
                            const std::vector<PlacedFiducial>& fiducials) {
    std::vector<PlacedSymmetry> models;
    for (std::size_t g : placing)
        if (g < fiducials.size() && fiducials[g].model)
            models.push_back(
                {&fiducials[g].model->dense, &fiducials[g].model->symmetry, fiducials[g].T_machine_fiducial});
    std::size_t source = 0;
    if (models.empty() || !common_symmetry(models, nullptr, &source)) return "";
    const PlacedFiducial& f = fiducials[placing[source]];
    if (placing.size() == 1)
        return "ambiguous by the symmetry of " + f.name + ": " + f.model->symmetry.sentence() +
               " (its own frame), and no other fiducial in view tells its turns apart";
    return "ambiguous by the symmetry of " + names_of(fiducials, placing) + ": a turn that maps " + f.name +
           " onto itself (" + f.model->symmetry.sentence() +
           ", its own frame) maps the others onto themselves too";
}

ScanRegistration register_scan(const PreparedScan& scan, const std::vector<PlacedFiducial>& fiducials,
                               const LocalizeSettings& localize, const RegistrationSettings& settings) {
    Search search(scan, fiducials, localize, settings);
    search.all();
    corroborate_and_refute(search.hyps, fiducials, settings);
    ScanRegistration r;
    const Hypothesis* top = best_hypothesis(search.hyps);
    r.fits = search.fits(top);
    const auto done = [&](std::string reason) {
        r.reason = std::move(reason);
        r.hypotheses = std::move(search.hyps);
        return r;
    };
    if (!top) {
        std::string why = "no fiducial fits:";
        if (search.hyps.empty())
            for (const auto& f : r.fits) why += " " + f.fiducial + ": " + f.reason + ";";
        else
            for (const auto& h : search.hyps) why += " " + h.refuted + ";";
        why.pop_back();
        return done(why);
    }
    const double noise = scan.scale.noise;
    if (std::string why = symmetry_reason(top->explained, fiducials); !why.empty()) return done(why);
    if (std::string why = rival_reason(*top, search.hyps, fiducials, noise, localize, settings); !why.empty())
        return done(why);
    for (std::size_t g : top->contradicted) {
        if (top->explained.size() >= 2) r.moved.push_back(g);
        r.warnings.push_back("fiducial " + fiducials[g].name +
                             " is not where its probed pose puts it, while " +
                             std::to_string(top->explained.size()) +
                             " others agree: it moved or was probed wrong; left out of this scan's fit");
    }
    // Every fiducial the winning hypothesis explains fixes the scan together. Each one's own fit must agree
    // with the others' within what the noise explains; one that does not has moved or was probed wrong.
    std::vector<std::size_t> in_view = top->explained;
    ScanPoseFit joint = search.joint_fit(in_view, top->T_machine_scan);
    if (joint.valid && in_view.size() >= 2) {
        const auto bad = search.disagreements(in_view, joint.T_machine_scan);
        if (!bad.empty() && in_view.size() >= 3) {
            // Which one moved: the fiducial without which the others agree, while it disagrees with them.
            // Not the one whose own fit moves most from the joint fit: that fit is pulled towards the moved
            // one, and a fiducial the scan holds weakly moves most (issue 27: A's probed x 0.5 mm off, and
            // the warning named C).
            struct Culprit {
                Search::Disagreement d;
                std::vector<std::size_t> rest;
                ScanPoseFit fit;
            };
            std::vector<Culprit> culprits;
            for (std::size_t k : in_view) {
                std::vector<std::size_t> rest;
                for (std::size_t j : in_view)
                    if (j != k) rest.push_back(j);
                ScanPoseFit without = search.joint_fit(rest, top->T_machine_scan);
                if (!without.valid || !search.disagreements(rest, without.T_machine_scan).empty()) continue;
                const auto alone = search.disagreements({k}, without.T_machine_scan);
                if (alone.empty()) continue;
                culprits.push_back({alone.front(), std::move(rest), std::move(without)});
            }
            if (culprits.size() != 1)
                return done("fiducials " + names_of(fiducials, in_view) + " disagree" +
                            format(" by up to %.3g", bad.front().shift) +
                            " here, and no one of them alone: one or more moved or were probed wrong");
            const Culprit& c = culprits.front();
            r.warnings.push_back("fiducial " + fiducials[c.d.k].name + " disagrees with the others" +
                                 format(" by %.3g at the fiducial and %.3g deg", c.d.shift, c.d.turn_deg) +
                                 ": it moved or was probed wrong; left out of this scan's fit");
            r.moved.push_back(c.d.k);
            in_view = c.rest;
            joint = c.fit;
            // The others alone may share a turn that the one left out told apart.
            if (std::string why = symmetry_reason(in_view, fiducials); !why.empty()) return done(why);
        } else if (!bad.empty()) {
            return done("fiducials " + names_of(fiducials, in_view) + " disagree" +
                        format(" by up to %.3g", bad.front().shift) +
                        " here: one of them moved or was probed wrong");
        }
    }
    // The scanner's scale, where two fiducials or more measure it through their distances (scale_fit.hpp).
    std::optional<ScaleFit> scaled;
    if (settings.fit_scale && joint.valid && in_view.size() >= 2) {
        std::vector<const PreparedModel*> ms;
        std::vector<Eigen::Isometry3d> ps;
        search.subset(in_view, ms, ps);
        const Surface target = make_pose_target(ms, ps);
        // About the points' centroid: T_machine_scan stays the rigid map that places them (scale_fit.hpp).
        Eigen::Vector3d centre = Eigen::Vector3d::Zero();
        for (const auto& p : joint.source) centre += p;
        centre /= std::max<double>(1.0, static_cast<double>(joint.source.size()));
        ScaleFit f = fit_scale(joint.source, &joint.source_normals, target, joint.T_machine_scan, centre,
                               joint.inlier_distance);
        if (f.valid && std::abs(f.scale - 1.0) > settings.max_scale_error)
            return done(
                "fiducials " + names_of(fiducials, in_view) +
                format(" lie %.2f%% ", 100.0 * std::abs(1.0 / f.scale - 1.0)) +
                (f.scale < 1.0 ? "further apart" : "nearer together") +
                " in the scan than their probed poses put them: one of them moved or was probed wrong, "
                "or the scanner's scale is off by that much" +
                format(" (allowed: %.2f%%)", 100.0 * settings.max_scale_error));
        // Used where the data tell it from 1: a scale the fiducials hardly fix (two close together, seen
        // from afar) would move the part by its own error, further than the rigid fit is off.
        if (f.valid && std::abs(f.scale - 1.0) >
                           settings.scale_significance * f.scale_sigma_per_noise * scan.scale.noise)
            scaled = std::move(f);
    }
    // A direction that only surfaces seen edge-on hold: there a sensor's smoothing and edge dropout move the
    // points most, and the fit slides along it.
    Matrix6d whole = top->source_fit.JtJ, facing = top->source_fit.JtJ_facing;
    if (joint.valid) {
        whole.setZero();
        for (const auto& h : joint.JtJ_per_model) whole += h;
        facing = joint.JtJ_facing;
    }
    const double share = least_share(facing, whole);
    if (share < settings.min_facing_share)
        return done("one direction is held only by surfaces seen edge-on, and the fit can slide along it" +
                    format(" (%.1f%% of its hold from surfaces the scanner faces; needs %.1f%%)",
                           100.0 * share, 100.0 * settings.min_facing_share));
    r.valid = true;
    r.fiducials = in_view;
    r.source = top->source;
    r.corroborated = top->corroborated > 0;
    r.T_machine_scan = joint.valid ? joint.T_machine_scan : top->T_machine_scan;
    r.score = top->source_fit.score;
    r.rmse = joint.valid ? joint.rmse : top->source_fit.rmse;
    if (joint.valid) {
        r.information = joint.JtJ / std::max(noise * noise, 1e-30);
        r.JtJ_per_fiducial = joint.JtJ_per_model;
    }
    if (scaled) {
        r.T_machine_scan = scaled->T_machine_scan;
        r.scale_centre = scaled->centre;
        r.scale = scaled->scale;
        r.scale_sigma = scaled->scale_sigma_per_noise * noise;
        r.rmse = scaled->rmse;
        r.information = scaled->JtJ_pose / std::max(noise * noise, 1e-30);  // the scale not known either
    }
    r.fits[top->source] = top->source_fit;
    // The fits say of each fiducial what the scan's status says (issue 27: "registered by A,B,C" beside a
    // row that called A rejected, its own search's best candidate, while the winner's pose explained it):
    // accepted exactly when it fixes the scan.
    const auto among = [](const std::vector<std::size_t>& v, std::size_t k) {
        return std::find(v.begin(), v.end(), k) != v.end();
    };
    for (std::size_t k = 0; k < r.fits.size() && k < top->judged.size(); ++k) {
        FiducialFit& f = r.fits[k];
        if (among(in_view, k)) {
            if (k != top->source && !f.valid) {
                f = top->judged[k];
                f.searched = false;  // accepted where the others put it
            }
            f.valid = true;
            f.reason.clear();
        } else if (among(r.moved, k)) {
            if (f.valid || f.reason.empty()) f = top->judged[k];
            f.valid = false;
            f.searched = false;
            f.reason =
                "not where its probed pose puts it, while the others agree: it moved or was probed wrong; "
                "left out of this scan's fit";
        } else if (f.valid) {
            f.valid = false;
            f.reason = "not used: it does not fit where the scan's other fiducials put it";
        }
    }
    return done("");
}

}  // namespace partloc
