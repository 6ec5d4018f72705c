#include "partloc/pipeline/run.hpp"

#include <open3d/geometry/BoundingVolume.h>
#include <open3d/geometry/KDTreeSearchParam.h>
#include <tbb/global_control.h>
#include <tbb/parallel_for.h>
#include <tbb/task_group.h>

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <exception>
#include <optional>
#include <stdexcept>

#include "partloc/core/cloud_stats.hpp"
#include "partloc/core/icp.hpp"
#include "partloc/core/localize.hpp"
#include "partloc/core/normals.hpp"
#include "partloc/core/radius_grid.hpp"
#include "partloc/core/stock.hpp"
#include "partloc/core/workpiece_fit.hpp"
#include "partloc/pipeline/uncertainty.hpp"

namespace partloc {

namespace {

/// Points per fiducial in the fits that place or judge a hypothesis (the scan's final fit takes all): a
/// thousand or two fix a pose to hundredths of a millimetre, far inside the tolerances those fits are judged
/// by, and cost a tenth of the 10-20 thousand a fiducial shows in a scan of 250 k points (issue 3). 3000
/// before (localize.cpp, kFinePoints).
constexpr std::size_t kHypothesisPoints = 1500;

using Clock = std::chrono::steady_clock;
double seconds_since(Clock::time_point t0) {
    return std::chrono::duration<double>(Clock::now() - t0).count();
}

std::string fmt(const char* f, double a, double b = 0, double c = 0) {
    char buf[256];
    std::snprintf(buf, sizeof buf, f, a, b, c);
    return buf;
}


double median_of(std::vector<double> v) {
    std::sort(v.begin(), v.end());
    return v.empty() ? 0.0 : v[v.size() / 2];
}

/// At most this many merged points go to the part's fit (it thins them further for its coarse stages).
constexpr std::size_t kMergedPoints = 150000;
/// The workpiece points the part's last fit looks at, at most (every k-th of each scan's beyond).
constexpr std::size_t kReferencePoints = 1500000;

/// The largest 1-sigma shift, in any direction, of point a under a registration with this information
/// (twist [w, v] about the origin); 0 when the information is empty.
double sigma_at(const Matrix6d& information, const Eigen::Vector3d& a) {
    Eigen::SelfAdjointEigenSolver<Matrix6d> es(information);
    if (!(es.eigenvalues()(5) > 0)) return 0.0;
    Vector6d inv = Vector6d::Zero();
    for (int k = 0; k < 6; ++k)
        if (es.eigenvalues()(k) > 1e-12 * es.eigenvalues()(5)) inv(k) = 1.0 / es.eigenvalues()(k);
    const Matrix6d cov = es.eigenvectors() * inv.asDiagonal() * es.eigenvectors().transpose();
    const Eigen::Matrix3d c = shift_covariance_at(cov, a);
    return std::sqrt(std::max(0.0, Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(c).eigenvalues()(2)));
}

struct ScanWork {
    Scale scale;
    /// Machine frame, axes 0. Its normals (facing the scanner) are computed where they are used, by
    /// normals_at: the merge keeps a fraction of the points (a third on seed 106, a twentieth with 2 M points
    /// per scan, where normals for every point took 2.5 of 19 s). A zero normal is one not computed yet
    /// (estimate_normals gives unit normals only).
    std::shared_ptr<open3d::geometry::PointCloud> workpiece_points;
    Eigen::Vector3d eye = Eigen::Vector3d::Zero();  ///< the scanner, same frame
    std::shared_ptr<RadiusGrid> grid;  ///< normals_at's neighbour grid over workpiece_points, once asked

    /// Computes the normals of workpiece points `idx` that have none yet; the same normals whenever asked
    /// (from all of the scan's workpiece points around each).
    void normals_at(const std::vector<std::size_t>& idx) {
        if (!workpiece_points || workpiece_points->normals_.size() != workpiece_points->points_.size()) return;
        auto& c = *workpiece_points;
        std::vector<std::size_t> missing;
        for (std::size_t k : idx)
            if (c.normals_[k].squaredNorm() == 0.0) missing.push_back(k);
        if (missing.empty()) return;
        // 2.5 spacings, about twenty points: 3.5 spacings and thirty took a fifth more of the merge's time
        // (seed 106). They tell the faces apart in the part's fit and orient the stock's surface.
        // The neighbour grid is built once: the merge, the lone-scan check and the part's last fit ask in
        // turn.
        const double radius = 2.5 * scale.spacing;
        if (!grid) grid = std::make_shared<RadiusGrid>(normals_grid(c.points_, radius));
        const auto n = estimate_normals(c.points_, *grid, radius, 20, &missing);
        for (std::size_t j = 0; j < missing.size(); ++j)
            c.normals_[missing[j]] = facing(n[j], c.points_[missing[j]], eye);
    }
    void all_normals() {
        if (!workpiece_points) return;
        std::vector<std::size_t> all(workpiece_points->points_.size());
        for (std::size_t k = 0; k < all.size(); ++k) all[k] = k;
        normals_at(all);
    }
};

/// Takes back a scan's registration: rejected, with the reason (its fits stay, for the report).
void unregister(ScanResult& r, std::string message) {
    r.registered = false;
    r.fiducials.clear();
    r.T_machine_scan = Eigen::Isometry3d::Identity();
    r.information = Matrix6d::Zero();
    r.fiducial_jtj.clear();
    r.score = r.rmse = 0.0;
    r.warnings.clear();
    r.message = std::move(message);
}

/// The scans registered by one fiducial alone that the part does not confirm (part_disowns_scan): a look-alike
/// of that fiducial, or that fiducial moved, placed them. Such scans are marked not registered, with the
/// reason; returns whether any was. A lone scan that the merged fit located the part from by itself is
/// confirmed by that fit.
bool reject_inconsistent_scans(std::vector<ScanWork>& work, const WorkpieceFit& fit,
                               const Surface& reference, const WorkpieceFitSettings& wfs,
                               std::vector<ScanResult>& scans) {
    std::size_t registered = 0;
    for (const auto& r : scans) registered += r.registered;
    if (registered == 0 || (registered == 1 && fit.ok)) return false;
    bool any = false;
    for (std::size_t i = 0; i < scans.size(); ++i) {
        ScanResult& r = scans[i];
        if (!r.registered || r.fiducials.size() >= 2 || !work[i].workpiece_points) continue;
        work[i].all_normals();
        const auto& wp = *work[i].workpiece_points;
        const std::string why =
            part_disowns_scan(wp.points_, wp.HasNormals() ? &wp.normals_ : nullptr, fit, reference, wfs);
        if (why.empty()) continue;
        const std::string name = r.fiducials.front();
        unregister(r, "only " + name + "'s fit places this scan, and " + why + ": " + name +
                          " moved, or a shape like it elsewhere placed the scan");
        any = true;
    }
    return any;
}

}  // namespace

JobResult run_job(const Job& job, const RunSettings& settings) {
    const auto t0 = Clock::now();
    std::optional<tbb::global_control> threads;
    if (settings.threads > 0) threads.emplace(tbb::global_control::max_allowed_parallelism, settings.threads);

    if (job.fiducials.empty()) throw std::invalid_argument("the job has no fiducials");
    for (const auto& f : job.fiducials) {
        job.machine.motion(f.moves_with, f.probed_at);  // throws on an unknown axis
    }
    job.machine.motion(job.workpiece.moves_with, {});

    JobResult result;
    result.units = job.units;
    result.scans.resize(job.scans.size());
    std::vector<ScanWork> work(job.scans.size());

    // Scale of each scan: the scanner's specification where given, else measured on the scan.
    tbb::parallel_for(std::size_t(0), job.scans.size(), [&](std::size_t i) {
        const auto& pts = *job.scans[i].points;
        CloudStats m;
        if (!job.scanner.point_spacing || !job.scanner.noise) m = measure_cloud(pts, 3000, settings.seed + i);
        Scale s;
        s.spacing = job.scanner.point_spacing.value_or(m.spacing);
        s.noise = job.scanner.noise.value_or(m.noise);
        // Smoothed or quantised data can report almost no scatter; a floor keeps thresholds sane.
        s.noise = std::max(s.noise, 0.05 * s.spacing);
        work[i].scale = s;
    });

    // One sampling for the global fit, from the fiducials' size (Drost: 0.03-0.05 of the diameter), never
    // finer than the scans resolve.
    std::vector<double> diameters, spacings;
    for (const auto& f : job.fiducials) diameters.push_back(bounding_box(f.model).diagonal().norm());
    for (const auto& w : work)
        if (w.scale.spacing > 0) spacings.push_back(w.scale.spacing);
    const double spacing = spacings.empty() ? 0.0 : median_of(spacings);
    const double max_spacing = spacings.empty() ? 0.0 : *std::max_element(spacings.begin(), spacings.end());
    const double sampling = std::max(0.04 * median_of(diameters), 2.5 * max_spacing);

    std::vector<PreparedModel> models(job.fiducials.size());
    tbb::parallel_for(std::size_t(0), job.fiducials.size(), [&](std::size_t k) {
        const auto& f = job.fiducials[k];
        const double dense = std::max(spacing, diameters[k] / 150.0);
        models[k] =
            settings.models
                ? settings.models->prepare(f.name, f.model.mesh.get(), f.model.points.get(), dense, sampling)
                : prepare_model(f.name, f.model.mesh.get(), f.model.points.get(), dense, sampling);
    });

    // The workpiece region: the crop box, or the nominal part with a margin for its uncertain pose.
    const Eigen::AlignedBox3d region = workpiece_region(job, spacing);

    // The processor (§3.4.1), scans in parallel; each scan's outcome depends on that scan alone.
    LocalizeSettings ls;
    tbb::parallel_for(std::size_t(0), job.scans.size(), [&](std::size_t i) {
        const auto ts = Clock::now();
        const Scan& scan = job.scans[i];
        ScanResult& r = result.scans[i];
        r.file = scan.file;
        r.points = scan.points->points_.size();
        r.point_spacing = work[i].scale.spacing;
        r.noise = work[i].scale.noise;
        if (r.points < 100 || work[i].scale.spacing <= 0) {
            r.message = "too few valid points (" + std::to_string(r.points) + ")";
            return;
        }
        const Eigen::Vector3d viewpoint = estimate_viewpoint(*scan.points, work[i].scale.spacing);
        const PreparedScan ps = prepare_scan(*scan.points, work[i].scale, sampling, viewpoint);
        const std::size_t M = models.size();
        std::vector<std::vector<FiducialFit>> candidates(M);  // each fiducial's own fits, where searched
        std::vector<char> searched(M, 0);
        // Every candidate that passed its own checks is a hypothesis for where the scanner was. The fiducials
        // are a rigid constellation of known poses, so a hypothesis predicts every fiducial in the scan: any
        // predicted fiducial the scanner saw through refutes it (a block of like shape elsewhere, or a
        // fiducial that moved). Among the rest, the one that explains most points wins (§3.4.1: the best
        // fiducial wins, here the best constellation).
        struct Hypothesis {
            std::size_t source_k = 0;
            Eigen::Isometry3d T_initial;     ///< from the source fiducial alone
            Eigen::Isometry3d T_machine_scan;  ///< refined on every fiducial
            double support = 0.0;
            std::vector<std::string> names;
            std::vector<std::size_t> contradicted;  ///< fiducials the scan contradicts where this puts them
            std::string refuted;
            int corroborated = 0;  ///< other fiducials whose own fits put the scanner about here
            const FiducialFit* source = nullptr;
            std::vector<FiducialFit>
                judged;  ///< every fiducial judged where this puts it, in the models' order
        };
        std::vector<const PreparedModel*> all_models;
        std::vector<Eigen::Isometry3d> all_poses;
        for (std::size_t g = 0; g < models.size(); ++g) {
            all_models.push_back(&models[g]);
            all_poses.push_back(fiducial_at(job.machine, job.fiducials[g], scan.axes));
        }
        auto judge_at = [&](Hypothesis& h, const Eigen::Isometry3d& T) {
            h.T_machine_scan = T;
            h.support = 0.0;
            h.names.clear();
            h.contradicted.clear();
            h.judged.clear();
            bool source_ok = false;
            for (std::size_t g = 0; g < models.size(); ++g) {
                const FiducialFit& e =
                    h.judged.emplace_back(evaluate_model(ps, models[g], T.inverse() * all_poses[g], ls));
                if (e.seen_through >= 20 && e.violation > 4.0 * ls.max_violation) {
                    h.contradicted.push_back(g);
                } else if (e.accepted) {
                    h.support += support(e);
                    h.names.push_back(job.fiducials[g].name);
                    source_ok = source_ok || g == h.source_k;
                }
            }
            return source_ok;
        };
        std::vector<Hypothesis> hyps;
        std::optional<Surface> all_target;  // every fiducial at its pose: one target for all the starts
        // Fiducial ks's global and fine fits, and a hypothesis from each of their candidates that passed.
        const auto search = [&](const std::vector<std::size_t>& ks) {
            std::vector<const PpfModel*> tables;
            for (std::size_t k : ks) tables.push_back(models[k].ppf.get());
            const auto global = ppf_detect(tables, ps.coarse_points, ps.coarse_normals);
            for (std::size_t j = 0; j < ks.size(); ++j) {
                const std::size_t k = ks[j];
                searched[k] = 1;
                candidates[k] = fit_candidates(ps, models[k], ls, global[j]);
                for (const auto& c : candidates[k]) {
                    if (!c.accepted) continue;
                    Hypothesis h;
                    h.source = &c;
                    h.source_k = k;
                    h.T_initial = all_poses[k] * c.T_scan_fiducial.inverse();
                    // Refined on every fiducial at once before the others are judged: one fiducial seen with
                    // a weakly held direction can be off by tenths of a millimetre, enough to make the scan
                    // seem to contradict another fiducial that is really there. If the refinement loses the
                    // source fiducial itself (another one, moved, pulled it away), it is judged where its
                    // source put it.
                    bool judged = false;
                    if (M > 1) {
                        if (!all_target) all_target.emplace(make_pose_target(all_models, all_poses));
                        const ScanPoseFit joint =
                            fit_scan_pose(ps, all_models, all_poses, h.T_initial, ls, 0.5 * sampling,
                                          &*all_target, kHypothesisPoints);
                        if (joint.ok && pose_error(joint.T_machine_scan, h.T_initial).translation < sampling)
                            judged = judge_at(h, joint.T_machine_scan);
                    }
                    if (!judged) judge_at(h, h.T_initial);
                    hyps.push_back(std::move(h));
                }
            }
        };
        // The fiducials are searched one at a time, in the job's order. A hypothesis under which at least one
        // other fiducial passes its checks where its probed pose puts it, none is contradicted, and every
        // fiducial not yet searched either passes too or shows nothing there (out of view or hidden: no
        // points on it, none seen through it), is already corroborated: a look-alike rarely has another
        // fiducial in the right place beside it. The searches not yet made could then only add hypotheses of
        // the same placement, or lone ones that do not outweigh it; they are skipped (seed 106: four scans of
        // six skip B; the voting and the candidates' fits are about two thirds of a scan's time).
        const auto settles = [&](const Hypothesis& h) {
            if (!h.contradicted.empty() || h.names.size() < 2) return false;
            for (std::size_t g = 0; g < M; ++g) {
                const FiducialFit& e = h.judged[g];
                if (!searched[g] && !e.accepted && (e.inliers >= ls.min_inliers || e.seen_through >= 20))
                    return false;
            }
            return true;
        };
        search({0});
        if (settings.search_every_fiducial) {
            std::vector<std::size_t> rest;  // together, in one pass over the scan's pairs
            for (std::size_t k = 1; k < M; ++k) rest.push_back(k);
            if (!rest.empty()) search(rest);
        } else {
            for (std::size_t k = 1; k < M && !std::any_of(hyps.begin(), hyps.end(), settles); ++k)
                search({k});
        }
        // Two fiducials whose own fits put the scanner at about the same place corroborate each other: a
        // look-alike rarely has a second look-alike in the right place beside it. Where such a hypothesis
        // contradicts a third fiducial (or one of them, slightly), that fiducial has moved or was probed
        // wrong; it is named and left out, instead of the scan being lost or, worse, a lone look-alike
        // winning.
        for (auto& h : hyps)
            for (const auto& o : hyps) {
                if (o.source_k == h.source_k) continue;
                const Eigen::Isometry3d D = o.T_initial * h.T_initial.inverse();
                const Eigen::Vector3d c = all_poses[h.source_k] * models[h.source_k].dense.center;
                if (rotation_angle_deg(D.linear()) < 2.0 && (D * c - c).norm() < 2.0 * sampling) ++h.corroborated;
            }
        for (auto& h : hyps) {
            if (h.names.size() >= 2) h.corroborated = std::max<int>(h.corroborated, 1);
            if (!h.contradicted.empty() && h.corroborated == 0) {
                const std::size_t g = h.contradicted.front();
                h.refuted = "with " + job.fiducials[h.source_k].name + " as found, the scan contradicts " +
                            job.fiducials[g].name +
                            " where its probed pose puts it (a look-alike, or it moved or was probed wrong)";
            } else if (h.names.empty()) {
                h.refuted = "with " + job.fiducials[h.source_k].name + " as found, no fiducial passes its checks";
            }
        }
        // Corroborated hypotheses first, then by support.
        const Hypothesis* top = nullptr;
        for (const auto& h : hyps) {
            if (!h.refuted.empty()) continue;
            if (!top || (h.corroborated > 0) > (top->corroborated > 0) ||
                ((h.corroborated > 0) == (top->corroborated > 0) && h.support > top->support))
                top = &h;
        }
        for (std::size_t k = 0; k < M; ++k) {
            if (!searched[k]) {
                // Not searched only when a hypothesis settled the scan; that one is corroborated and not
                // refuted, so there is a winner. Judged where the winner puts it.
                r.fits.push_back(top->judged[k]);
                r.fits.back().searched = false;
            } else if (candidates[k].empty()) {
                FiducialFit none;
                none.fiducial = models[k].name;
                none.reason = "no candidate pose: nothing in the scan is shaped like this fiducial";
                r.fits.push_back(none);
            } else {
                r.fits.push_back(candidates[k].front());
            }
        }
        if (!top) {
            r.message = "no fiducial fits:";
            if (hyps.empty())
                for (const auto& f : r.fits) r.message += " " + f.fiducial + ": " + f.reason + ";";
            else
                for (const auto& h : hyps) r.message += " " + h.refuted + ";";
            r.message.pop_back();
            return;
        }
        auto names_of = [&](const std::vector<std::size_t>& ks) {
            std::string n;
            for (std::size_t k : ks) n += (n.empty() ? "" : " and ") + job.fiducials[k].name;
            return n;
        };
        for (const auto& h : hyps) {
            if (&h == top || !h.refuted.empty()) continue;
            if (top->corroborated > 0 && h.corroborated == 0) continue;  // a lone fit does not outweigh two
            const PoseError e = pose_error(h.T_machine_scan, top->T_machine_scan);
            if ((e.rotation_deg > 1.0 || e.translation > 5.0 * sampling) && h.support >= ls.ambiguity * top->support) {
                r.message = "ambiguous: two placements of the scanner explain the scan about equally well" +
                            fmt(" (%.3g deg, %.3g apart)", e.rotation_deg, e.translation);
                return;
            }
            // Two sets of fiducials, each agreeing within itself, that put the scanner apart by more than
            // the noise explains: a fiducial that one set has and the other lacks moved or was probed wrong,
            // and this scan cannot tell which.
            if (h.corroborated > 0 && h.names != top->names) {
                const Eigen::Isometry3d D = h.T_machine_scan * top->T_machine_scan.inverse();
                const Eigen::Vector3d c = all_poses[top->source_k] * models[top->source_k].dense.center;
                if ((D * c - c).norm() > 3.0 * work[i].scale.noise) {
                    std::vector<std::size_t> differ;
                    for (std::size_t g = 0; g < models.size(); ++g) {
                        const auto& n = job.fiducials[g].name;
                        const bool a = std::count(top->names.begin(), top->names.end(), n) > 0;
                        const bool b = std::count(h.names.begin(), h.names.end(), n) > 0;
                        if (a != b) differ.push_back(g);
                    }
                    r.message = "fiducials " + names_of(differ) + fmt(" disagree by %.3g here", (D * c - c).norm()) +
                                ": one of them moved or was probed wrong";
                    return;
                }
            }
        }
        // A scanner pose that one fiducial's fit alone supports is trusted only when no other fit that passed
        // its own checks, refuted or not, puts the scanner elsewhere with half its support: a near-symmetric
        // block, or a shape close to a fiducial's mirror image, fits in more than one way, and a look-alike
        // of one fiducial can hide where another is (measured: a mirrored model registered a scan 236 mm off
        // until this check).
        if (top->corroborated == 0) {
            const double own = support(*top->source);
            for (const auto& h : hyps) {
                if (&h == top || support(*h.source) < 0.5 * own) continue;
                const Eigen::Isometry3d D = h.T_initial * top->T_initial.inverse();
                const Eigen::Vector3d c = all_poses[top->source_k] * models[top->source_k].dense.center;
                if (rotation_angle_deg(D.linear()) > 1.0 || (D * c - c).norm() > 5.0 * sampling) {
                    r.message = "ambiguous: " + job.fiducials[top->source_k].name +
                                " alone puts the scanner here, and " + job.fiducials[h.source_k].name +
                                "'s fit, which passes its own checks, puts it elsewhere" +
                                fmt(" (%.3g deg, %.3g apart)", rotation_angle_deg(D.linear()), (D * c - c).norm());
                    return;
                }
            }
        }
        if (!top->contradicted.empty()) {
            if (top->names.size() < 2) {
                // One fiducial against another: this scan cannot tell which of the two moved.
                std::vector<std::size_t> both = {top->source_k};
                both.insert(both.end(), top->contradicted.begin(), top->contradicted.end());
                r.message = "fiducials " + names_of(both) +
                            " disagree here: one of them moved or was probed wrong (see the other scans)";
                return;
            }
            for (std::size_t g : top->contradicted)
                r.warnings.push_back("fiducial " + job.fiducials[g].name +
                                     " is not where its probed pose puts it, while " + std::to_string(top->names.size()) +
                                     " others agree: it moved or was probed wrong; left out of this scan's fit");
        }
        // Every fiducial the winning hypothesis explains fixes the scan together (issue 4). Each one's own fit
        // must agree with the others' within what the noise explains; one that does not has moved or was
        // probed wrong.
        std::vector<std::size_t> in_view;
        for (const auto& name : top->names)
            for (std::size_t k = 0; k < models.size(); ++k)
                if (job.fiducials[k].name == name) in_view.push_back(k);
        auto joint_fit = [&](const std::vector<std::size_t>& ks) {
            std::vector<const PreparedModel*> ms;
            std::vector<Eigen::Isometry3d> poses;
            for (std::size_t k : ks) {
                ms.push_back(&models[k]);
                poses.push_back(fiducial_at(job.machine, job.fiducials[k], scan.axes));
            }
            const bool all = ks.size() == models.size() && all_target;  // in_view keeps the models' order
            return fit_scan_pose(ps, ms, poses, top->T_machine_scan, ls, 0.0, all ? &*all_target : nullptr);
        };
        ScanPoseFit joint = joint_fit(in_view);
        const double noise = work[i].scale.noise;
        // How far fiducial k's own fit, started at `T`, moves the scan: at the fiducial, and in rotation.
        struct Disagreement {
            std::size_t k;
            double shift, turn_deg;
        };
        auto disagreements = [&](const Eigen::Isometry3d& T) {
            std::vector<Disagreement> out;
            for (std::size_t k : in_view) {
                const Eigen::Isometry3d F = fiducial_at(job.machine, job.fiducials[k], scan.axes);
                const ScanPoseFit own = fit_scan_pose(ps, {&models[k]}, {F}, T, ls, 0.5 * models[k].sampling,
                                                      nullptr, kHypothesisPoints);
                if (!own.ok) continue;
                const Eigen::Isometry3d D = own.T_machine_scan * T.inverse();
                const Eigen::Vector3d c = F * models[k].dense.center;
                const double shift = (D * c - c).norm(), turn = rotation_angle_deg(D.linear());
                const double turn_tol = 3.0 * noise / (0.5 * models[k].dense.diameter) * 180.0 / M_PI;
                if (shift > 3.0 * noise || turn > turn_tol) out.push_back({k, shift, turn});
            }
            return out;
        };
        if (joint.ok && in_view.size() >= 2) {
            const auto bad = disagreements(joint.T_machine_scan);
            if (!bad.empty() && in_view.size() >= 3 && bad.size() == 1) {
                // The others agree: this one moved or was probed wrong. Fit without it, and say so.
                const auto& b = bad.front();
                std::vector<std::size_t> rest;
                for (std::size_t k : in_view)
                    if (k != b.k) rest.push_back(k);
                const ScanPoseFit without = joint_fit(rest);
                if (without.ok) {
                    r.warnings.push_back("fiducial " + job.fiducials[b.k].name + " disagrees with the others" +
                                         fmt(" by %.3g at the fiducial and %.3g deg", b.shift, b.turn_deg) +
                                         ": it moved or was probed wrong; left out of this scan's fit");
                    in_view = rest;
                    joint = without;
                }
            } else if (!bad.empty()) {
                std::string names;
                for (std::size_t k : in_view) names += (names.empty() ? "" : " and ") + job.fiducials[k].name;
                r.message = "fiducials " + names + " disagree" + fmt(" by up to %.3g", bad.front().shift) +
                            " here: one of them moved or was probed wrong";
                return;
            }
        }
        const Eigen::Isometry3d T_machine_scan = joint.ok ? joint.T_machine_scan : top->T_machine_scan;
        r.registered = true;
        r.fiducials.clear();
        for (std::size_t k : in_view) r.fiducials.push_back(job.fiducials[k].name);
        r.T_machine_scan = T_machine_scan;
        r.score = top->source->score;
        r.rmse = joint.ok ? joint.rmse : top->source->rmse;
        if (joint.ok) {
            r.information = joint.JtJ / std::max(noise * noise, 1e-30);
            r.fiducial_jtj = joint.JtJ_models;
        }
        for (auto& f : r.fits)
            if (f.fiducial == top->source->fiducial) f = *top->source;

        // This scan's workpiece points, moved to the workpiece at the reference axis position (§3.4.2).
        const Eigen::Isometry3d T_machine0_scan =
            job.machine.motion(job.workpiece.moves_with, scan.axes).inverse() * T_machine_scan;
        auto wp = std::make_shared<open3d::geometry::PointCloud>();
        for (const auto& q : ps.cloud->points_) {
            const Eigen::Vector3d p = T_machine0_scan * q;
            if (region.contains(p)) wp->points_.push_back(p);
        }
        // Normals for the part's fit and the stock model, facing this scan's scanner, where they are used
        // (ScanWork::normals_at). Fewer than ten points: a scan that sees a fiducial and not the part.
        if (wp->points_.size() >= 10) {
            wp->normals_.assign(wp->points_.size(), Eigen::Vector3d::Zero());  // none computed yet
            work[i].eye = T_machine0_scan * ps.viewpoint;
        } else if (r.fiducials.size() < 2 && top->corroborated == 0) {
            // One fiducial's fit alone placed the scan, and it puts nothing of the scan where the part is:
            // a look-alike of that fiducial (measured: a scan with every fiducial point removed was
            // registered 222 mm off by a support block shaped like one), or a scan that misses the part,
            // which the part's fit could not use anyway.
            const std::string& name = job.fiducials[top->source_k].name;
            unregister(r, "only " + name + "'s fit places this scan, and it puts nothing of the scan in the "
                           "workpiece's region: " + name +
                           " moved, or a shape like it elsewhere placed the scan, or the scan misses the part");
            wp->points_.clear();
        } else {
            wp->points_.clear();
            r.warnings.push_back("registered, but it shows nothing of the workpiece in its region");
        }
        work[i].workpiece_points = wp;
        r.seconds = seconds_since(ts);
    });

    // The part (§3.4.2): merge, clean, fit the reference surfaces.
    const auto registered_count = [&] {
        return std::count_if(result.scans.begin(), result.scans.end(),
                             [](const ScanResult& r) { return r.registered; });
    };
    // The fit needs no more than a hundred thousand points or so: the registered scans' points are thinned by
    // their order, never by their position. A voxel grid picks or averages points by where they fall in
    // it, and on a face nearly parallel to its planes (a part squared to the machine) that depends on the
    // noise: one point per voxel turned seed 1001's small reference faces 0.10 degrees, the voxels' means
    // 0.08-0.13 degrees, against 0.003-0.008 for all the points (the fit at the true registration).
    // in_fit: the scans in the part's fit; a registered scan whose registration is too uncertain at the part
    // is left out of it (below), but not out of merged.ply and the stock.
    std::vector<char> in_fit(job.scans.size(), 1);
    // The registered scans' workpiece points (only those of the scans in the part's fit when fit_only),
    // thinned by their order to at most kMergedPoints, statistical outliers removed.
    const auto merge_registered = [&](bool fit_only) {
        auto m = std::make_shared<open3d::geometry::PointCloud>();
        const auto taken = [&](std::size_t i) { return result.scans[i].registered && (!fit_only || in_fit[i]); };
        std::size_t total = 0;
        for (std::size_t i = 0; i < job.scans.size(); ++i)
            if (taken(i)) total += work[i].workpiece_points->points_.size();
        const std::size_t stride = std::max<std::size_t>(1, (total + kMergedPoints - 1) / kMergedPoints);
        std::size_t at = 0;  // index into the concatenation, so that the stride runs on across scans
        std::vector<std::vector<std::size_t>> keep(job.scans.size());
        for (std::size_t i = 0; i < job.scans.size(); ++i) {
            if (!taken(i)) continue;
            const std::size_t n = work[i].workpiece_points->points_.size();
            for (std::size_t k = 0; k < n; ++k, ++at)
                if (at % stride == 0) keep[i].push_back(k);
        }
        // The scans' normals side by side: each scan's neighbour grid is built by one thread.
        tbb::parallel_for(std::size_t(0), job.scans.size(), [&](std::size_t i) {
            if (taken(i)) work[i].normals_at(keep[i]);
        });
        for (std::size_t i = 0; i < job.scans.size(); ++i) {
            if (!taken(i)) continue;
            const auto& c = *work[i].workpiece_points;
            for (std::size_t k : keep[i]) {
                m->points_.push_back(c.points_[k]);
                if (c.HasNormals()) m->normals_.push_back(c.normals_[k]);
            }
        }
        if (m->normals_.size() != m->points_.size()) m->normals_.clear();
        if (m->points_.size() > 30) m = m->SelectByIndex(statistical_inliers(m->points_, 20, 2.5));
        return m;
    };
    auto merged = merge_registered(true);
    // merged.ply's points (one per voxel of the scans' spacing) and the stock model from them, in a task: it
    // starts on the first merge, which is what is written unless a scan is later left out of the part's fit
    // or unregistered (then it starts again from those points, and the first one's stock is not built). It
    // runs beside the part's fits, the datums and the uncertainty, each phase's stretches on one core filling
    // the other. Seed 106 (in-process timers, two threads): started after the part's fits, it ended 0.05 s
    // after the uncertainty, and the scans' end to the result took 0.40 s; started here, the part's fits take
    // 0.06 s longer, the stock ends with the uncertainty, and the same stretch takes 0.37 s. When the part is
    // not located, a stock already being built is waited for. The stock is kept only when the part is
    // located.
    struct StockWork {
        std::shared_ptr<const open3d::geometry::PointCloud> input;
        std::shared_ptr<open3d::geometry::PointCloud> written;
        std::shared_ptr<open3d::geometry::TriangleMesh> stock;
        std::exception_ptr error;
        std::atomic<bool> abandoned{false};  ///< its stock is not wanted: not built if not yet started
    } early_stock, late_stock;
    tbb::task_group stock_task;
    struct WaitFor {
        tbb::task_group& group;
        ~WaitFor() { group.wait(); }  // also when leaving early; the task holds its own points
    } wait_for_stock{stock_task};
    const auto start_stock = [&stock_task, spacing, build = settings.build_stock](
                                 StockWork& out, std::shared_ptr<const open3d::geometry::PointCloud> points) {
        out.input = points;
        stock_task.run([&out, points, spacing, build] {
            try {
                out.written = points->VoxelDownSample(spacing);
                if (build && spacing > 0 && !out.abandoned) {
                    StockSettings ss;
                    ss.spacing = spacing;
                    out.stock = build_stock(*out.written, ss);
                }
            } catch (...) {
                out.error = std::current_exception();
            }
        });
    };
    start_stock(early_stock, merged);
    WorkpieceResult& w = result.workpiece;
    w.T_machine_workpiece_nominal = job.workpiece.T_machine_workpiece;
    w.fit = job.workpiece.fit == WorkpieceFitMode::Datums ? "datums" : "simultaneous";
    // The part not located, and why: the result as it stands, timed (the caller returns it at once).
    const auto not_located = [&](std::string why) {
        early_stock.abandoned = true;  // no stock without the part
        w.message = std::move(why);
        result.seconds = seconds_since(t0);
        return std::move(result);
    };
    if (registered_count() == 0) return not_located("no scan could be registered to the machine");

    const auto& ref = job.workpiece.reference_surfaces;
    const double ref_d = bounding_box(ref).diagonal().norm();
    const double ref_spacing = std::max(spacing, ref_d / 400.0);
    // Oriented samples of a nominal model (reference surfaces or a datum); null when it is empty.
    const auto oriented_samples = [&](const ModelSource& m) -> std::shared_ptr<open3d::geometry::PointCloud> {
        if (m.mesh && !m.mesh->triangles_.empty()) return sample_mesh(*m.mesh, ref_spacing);
        if (!m.points || m.points->points_.empty()) return nullptr;
        auto samples = std::make_shared<open3d::geometry::PointCloud>(*m.points);
        if (!samples->HasNormals()) {
            samples->EstimateNormals(open3d::geometry::KDTreeSearchParamKNN(20));
            samples->OrientNormalsConsistentTangentPlane(12);
        }
        return samples;
    };
    const auto ref_samples = oriented_samples(ref);
    if (!ref_samples) return not_located("the reference surfaces are empty");
    const Surface reference = make_surface(ref_samples, ref_spacing);
    std::vector<double> noises;
    for (const auto& s : result.scans)
        if (s.registered) noises.push_back(s.noise);
    WorkpieceFitSettings wfs;
    wfs.noise = median_of(noises);
    wfs.spacing = spacing;
    // A scan whose registration leaves the part uncertain by far more than the others' would pull the fit
    // its way with all its points: its error is common to them and does not average out (measured: seed
    // 1143, a scan placed by two fiducials seen so that its registration is uncertain by 0.076 mm (1 sigma)
    // along y at the part, against 0.001-0.009 for the other scans, was 0.21 mm off and put the part 0.074 mm
    // off). Such a scan stays registered (its points are in merged.ply and the stock) but the part is fitted
    // without it, when the others locate it.
    const auto has_points = [&](std::size_t i) {
        return work[i].workpiece_points && !work[i].workpiece_points->points_.empty();
    };
    std::vector<double> reg_sigma(job.scans.size(), 0.0);
    for (std::size_t i = 0; i < job.scans.size(); ++i) {
        const ScanResult& r = result.scans[i];
        if (!r.registered || !has_points(i)) continue;
        const Eigen::Vector3d a =
            job.machine.motion(job.workpiece.moves_with, job.scans[i].axes) * reference.center;
        reg_sigma[i] = sigma_at(r.information, a);
    }
    // Uncertain by more than the noise at the part is no registration (measured: seed 1430 with fiducial A
    // mirrored, a scan held by B and C alone, 0.59 mm (1 sigma) at the part, was 0.92 mm off).
    bool loose = false;
    for (std::size_t i = 0; i < job.scans.size(); ++i) {
        if (!result.scans[i].registered || !(reg_sigma[i] > wfs.noise)) continue;
        unregister(result.scans[i], fmt("its registration leaves the part uncertain by %.3g (1 sigma), more than "
                                        "the noise (%.3g): the fiducials in view hold it too loosely",
                                        reg_sigma[i], wfs.noise));
        loose = true;
    }
    if (loose) {
        merged = merge_registered(true);
        if (registered_count() == 0) return not_located("no scan could be registered to the machine");
    }
    std::vector<double> sigmas;  // of the scans still registered
    for (std::size_t i = 0; i < job.scans.size(); ++i)
        if (result.scans[i].registered && has_points(i)) sigmas.push_back(reg_sigma[i]);
    const double sigma_limit = std::max(0.1 * wfs.noise, 3.0 * median_of(sigmas));
    std::size_t kept = 0, left_out = 0;
    for (std::size_t i = 0; i < job.scans.size(); ++i) {
        if (!result.scans[i].registered) continue;
        in_fit[i] = !(reg_sigma[i] > sigma_limit);
        (in_fit[i] ? kept : left_out) += 1;
    }
    if (kept == 0) std::fill(in_fit.begin(), in_fit.end(), 1);
    if (kept && left_out) merged = merge_registered(true);
    WorkpieceFit fit = fit_reference_surfaces(merged->points_, reference, wfs,
                                              merged->HasNormals() ? &merged->normals_ : nullptr);
    if (kept && left_out && !fit.ok) {
        // The others alone do not locate the part: all of them, then.
        std::fill(in_fit.begin(), in_fit.end(), 1);
        merged = merge_registered(true);
        fit = fit_reference_surfaces(merged->points_, reference, wfs,
                                     merged->HasNormals() ? &merged->normals_ : nullptr);
    }
    // A scan that one fiducial's fit alone placed, whose part points do not lie on the part that the other
    // scans locate, was placed by a look-alike of that fiducial: it is left out and the part fitted again.
    // Where the part was not found at all, such a scan is not trusted either (measured: a mirrored model,
    // the only fiducial fit that passed in its scan, placed it 143 mm and 180 degrees off; no point of it
    // lay on the part).
    if (reject_inconsistent_scans(work, fit, reference, wfs, result.scans)) {
        bool any_in_fit = false;
        for (std::size_t i = 0; i < job.scans.size(); ++i) any_in_fit |= result.scans[i].registered && in_fit[i];
        if (!any_in_fit) std::fill(in_fit.begin(), in_fit.end(), 1);
        merged = merge_registered(true);
        if (registered_count() == 0) {
            return not_located("no scan could be registered to the machine: the part confirms none of them");
        }
        fit = fit_reference_surfaces(merged->points_, reference, wfs,
                                     merged->HasNormals() ? &merged->normals_ : nullptr);
    }
    // The last stage once more, on every point of the scans in the fit near the reference surfaces: the merge
    // thins the scans to 150 000 points and the fit's last stage to 60 000, and the part's turn is as
    // uncertain as the noise of the points on its reference faces makes it (trials: the rotation's RMS error
    // was the noise's bound). Measured on seed 106: 39 349 points on the surfaces against 13 115. These
    // points, with their normals, are also what the uncertainty's jackknife refits, so that it scatters as
    // this fit does.
    // With millions of points per scan, every k-th of them (at most about 1.5 million in all to look at).
    std::vector<std::shared_ptr<open3d::geometry::PointCloud>> on_reference(job.scans.size());
    std::size_t fit_points = merged->points_.size();  // what the part's last fit took
    if (fit.ok) {
        const Eigen::Isometry3d T_nominal_machine = fit.T_correction.inverse();
        std::size_t total = 0;
        for (std::size_t i = 0; i < job.scans.size(); ++i)
            if (result.scans[i].registered && in_fit[i] && has_points(i))
                total += work[i].workpiece_points->points_.size();
        const std::size_t stride = std::max<std::size_t>(1, (total + kReferencePoints - 1) / kReferencePoints);
        std::vector<Eigen::Vector3d> pts, nrm;
        const auto used = [&](std::size_t i) {
            return result.scans[i].registered && in_fit[i] && has_points(i);
        };
        // Each scan's points near the reference surfaces, with their normals; the scans side by side.
        std::vector<std::vector<std::size_t>> near_idx(job.scans.size());
        tbb::parallel_for(std::size_t(0), job.scans.size(), [&](std::size_t i) {
            if (!used(i)) return;
            const auto& c = *work[i].workpiece_points;
            const std::size_t n = (c.points_.size() + stride - 1) / stride;
            std::vector<char> near(n, 0);
            tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 4096), [&](const auto& r) {
                for (std::size_t k = r.begin(); k != r.end(); ++k) {
                    double d2 = 0.0;
                    const Eigen::Vector3d q = T_nominal_machine * c.points_[k * stride];
                    near[k] = reference.nearest(q, &d2, 2.0 * fit.distance) >= 0;
                }
            });
            for (std::size_t k = 0; k < n; ++k)
                if (near[k]) near_idx[i].push_back(k * stride);
            work[i].normals_at(near_idx[i]);
        });
        for (std::size_t i = 0; i < job.scans.size(); ++i) {
            if (!used(i)) continue;
            const auto& c = *work[i].workpiece_points;
            const auto& idx = near_idx[i];
            auto& o = on_reference[i] = std::make_shared<open3d::geometry::PointCloud>();
            for (std::size_t k : idx) {
                o->points_.push_back(c.points_[k]);
                o->normals_.push_back(c.normals_[k]);
            }
            pts.insert(pts.end(), o->points_.begin(), o->points_.end());
            nrm.insert(nrm.end(), o->normals_.begin(), o->normals_.end());
        }
        const IcpResult r = fit_last_stage(pts, reference, T_nominal_machine, fit.distance, &nrm);
        if (r.inliers >= fit.inliers) {
            fit_points = pts.size();
            fit.T_correction = r.T_target_source.inverse();
            fit.rmse = r.rmse;
            fit.inliers = r.inliers;
            fit.JtJ = r.JtJ;
        }
    }
    // What is written (merged.ply) and meshed into the stock: one point per voxel of the scans' spacing, of
    // every registered scan.
    for (std::size_t i = 0; i < job.scans.size(); ++i)
        if (result.scans[i].registered && !in_fit[i])
            result.scans[i].warnings.push_back(
                fmt("left out of the part's fit: its registration leaves the part uncertain by %.3g (1 sigma), "
                    "more than %.3g",
                    reg_sigma[i], sigma_limit));
    const bool all_in_fit = std::count(in_fit.begin(), in_fit.end(), 0) == 0;
    const auto to_write = all_in_fit ? merged : merge_registered(false);
    w.rmse = fit.rmse;
    w.points = fit_points;
    w.inliers = fit.inliers;
    w.information = fit.JtJ / std::max(wfs.noise * wfs.noise, 1e-30);
    if (!fit.ok) {
        result.merged = to_write->VoxelDownSample(spacing);
        return not_located(fit.reason);
    }
    // merged.ply's points and the stock model: made from the first merge, while the part is fitted (below),
    // or from the points written if those differ (a scan left out of the fit or no longer registered).
    StockWork& stock_work = to_write == early_stock.input ? early_stock : late_stock;
    if (&stock_work == &late_stock) {
        early_stock.abandoned = true;
        start_stock(late_stock, to_write);
    }
    // The merged points once the task is done; its error, if they are missing.
    const auto take_written = [&] {
        stock_task.wait();
        if (!stock_work.written && stock_work.error) std::rethrow_exception(stock_work.error);
        result.merged = stock_work.written;
    };
    // The datum hierarchy (3-2-1), from the simultaneous fit's pose; or, for a simultaneous fit, each
    // datum's residual there.
    Eigen::Isometry3d T_correction = fit.T_correction;
    std::vector<DatumSurface> datum_surfaces;
    DatumFitSettings datum_settings;
    if (!job.workpiece.datums.empty()) {
        std::vector<DatumSurface>& datums = datum_surfaces;
        for (const auto& d : job.workpiece.datums) {
            const auto samples = oriented_samples(d.surfaces);
            if (!samples) {
                take_written();
                return not_located("datum " + d.name + ": its surfaces are empty");
            }
            datums.push_back({d.name, make_surface(samples, ref_spacing)});
        }
        DatumFitSettings& ds = datum_settings;
        ds.noise = wfs.noise;
        ds.spacing = spacing;
        if (job.workpiece.fit == WorkpieceFitMode::Datums) {
            const DatumFit df = fit_datums(merged->points_, datums, fit.T_correction, ds);
            w.datums = df.datums;
            w.points = merged->points_.size();
            if (!df.ok) {
                take_written();
                return not_located(df.reason);
            }
            T_correction = df.T_correction;
            w.rmse = df.rmse;
            w.inliers = df.inliers;
            w.information = df.information / std::max(wfs.noise * wfs.noise, 1e-30);
        } else {
            w.datums = evaluate_datums(merged->points_, datums, fit.T_correction, ds);
        }
    }
    // The points scatter less about the fitted surfaces than the scanner's noise: its noise is along its
    // rays, and a surface seen at an angle shows only part of it along its normal (measured: 0.083 against
    // the scanner's 0.13 mm, seed 1080). The information is that of the points the fit used, so it takes
    // their scatter.
    if (w.rmse > 0 && w.rmse < wfs.noise) w.information *= (wfs.noise * wfs.noise) / (w.rmse * w.rmse);
    w.located = true;
    w.T_machine_workpiece = T_correction * job.workpiece.T_machine_workpiece;
    result.located = true;
    {
        UncertaintyInputs ui;
        // The jackknife refits what the fit took: every point near the reference surfaces for the
        // simultaneous fit (the part is located, so each fitted scan with points has them); for the datums'
        // fit, which takes the merged points, every k-th of each scan's workpiece points (the datums need
        // not lie on the reference surfaces).
        const bool on_reference_fit = job.workpiece.fit != WorkpieceFitMode::Datums;
        if (!on_reference_fit) ui.scan_points_most = 8000;
        for (std::size_t i = 0; i < job.scans.size(); ++i) {
            if (!result.scans[i].registered || !in_fit[i]) continue;
            if (!on_reference_fit || !on_reference[i]) {
                if (work[i].workpiece_points) {
                    std::vector<std::size_t> taken;
                    const std::size_t n = work[i].workpiece_points->points_.size();
                    for (std::size_t k = 0; k < n; k += scan_stride(n, ui.scan_points_most)) taken.push_back(k);
                    work[i].normals_at(taken);
                }
                ui.scan_points.push_back(work[i].workpiece_points);
            } else {
                ui.scan_points.push_back(on_reference[i]);
            }
            std::vector<std::size_t> used;
            for (const auto& name : result.scans[i].fiducials)
                for (std::size_t k = 0; k < job.fiducials.size(); ++k)
                    if (job.fiducials[k].name == name) used.push_back(k);
            ui.scan_fiducials.push_back(used);
            const AxisValues& q = job.scans[i].axes;
            std::vector<Eigen::Isometry3d> moved;
            for (std::size_t k : used)
                moved.push_back(job.machine.motion(job.fiducials[k].moves_with, q) *
                                job.machine.motion(job.fiducials[k].moves_with, job.fiducials[k].probed_at).inverse());
            ui.scan_fiducial_motion.push_back(moved);
            ui.scan_fiducial_jtj.push_back(result.scans[i].fiducial_jtj);
            ui.scan_to_axes0.push_back(job.machine.motion(job.workpiece.moves_with, q).inverse());
        }
        ui.reference = &reference;
        ui.T_correction = T_correction;
        ui.fit_distance = fit.distance;
        ui.noise = wfs.noise;
        ui.information = w.information;
        if (job.workpiece.fit == WorkpieceFitMode::Datums)
            ui.refit = [&](const std::vector<Eigen::Vector3d>& pts, const std::vector<Eigen::Vector3d>*)
                -> std::optional<Eigen::Isometry3d> {
                const DatumFit df = fit_datums(pts, datum_surfaces, T_correction, datum_settings);
                if (!df.ok) return std::nullopt;
                return df.T_correction;
            };
        estimate_uncertainty(job, ui, w);
    }

    if (job.workpiece.final_part && job.workpiece.final_part->mesh) {
        auto located = std::make_shared<open3d::geometry::TriangleMesh>(*job.workpiece.final_part->mesh);
        located->Transform(T_correction.matrix());
        result.final_part_located = located;
    }
    take_written();
    if (stock_work.error) std::rethrow_exception(stock_work.error);
    result.stock = std::move(stock_work.stock);
    result.seconds = seconds_since(t0);
    return result;
}

}  // namespace partloc
