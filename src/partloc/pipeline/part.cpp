#include "partloc/pipeline/part.hpp"

#include <tbb/parallel_for.h>

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>

#include "partloc/core/cloud_stats.hpp"
#include "partloc/core/format.hpp"
#include "partloc/core/median.hpp"
#include "partloc/core/normals.hpp"

namespace partloc {

namespace {

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

std::size_t count_of(const std::vector<char>& v) { return std::count(v.begin(), v.end(), 1); }

/// A scan whose registration leaves the part uncertain by more than the noise is no registration; one
/// uncertain by far more than the others' would pull the fit its way with all its points (its error is
/// common to them and does not average out): it stays registered, its points in merged.ply and the stock,
/// but the part is fitted without it when the others locate it.
void weigh_registrations(PartSelection& s, const PartInputs& in, double noise, const PartSettings& ps) {
    const auto& regs = *in.registrations;
    const auto& ev = *in.evidence;
    for (std::size_t i = 0; i < regs.size(); ++i)
        if (s.registered[i] && ev[i].has_points())
            s.sigma[i] = sigma_at(regs[i].information, in.part_at_scan[i]);
    for (std::size_t i = 0; i < regs.size(); ++i) {
        if (!s.registered[i] || !(s.sigma[i] > ps.loose * noise)) continue;
        s.registered[i] = 0;
        s.rejected[i] = format(
            "its registration leaves the part uncertain by %.3g (1 sigma), more than the noise (%.3g): the "
            "fiducials in view hold it too loosely",
            s.sigma[i], noise);
    }
    if (!s.any_registered()) {
        s.none_left = "no scan could be registered to the machine";
        return;
    }
    std::vector<double> sigmas;  // of the scans still registered
    for (std::size_t i = 0; i < regs.size(); ++i)
        if (s.registered[i] && ev[i].has_points()) sigmas.push_back(s.sigma[i]);
    s.sigma_limit = std::max(ps.left_out_floor * noise, ps.left_out_median * median_of(sigmas));
    std::size_t kept = 0;
    for (std::size_t i = 0; i < regs.size(); ++i) {
        if (!s.registered[i]) continue;
        s.in_fit[i] = !(s.sigma[i] > s.sigma_limit);
        kept += s.in_fit[i];
    }
    if (kept == 0) std::fill(s.in_fit.begin(), s.in_fit.end(), 1);
}

/// The selection that the fit `fit` of selection `s` leads to:
/// - where scans were left out of it and it fails, the fit takes them all;
/// - else a scan that one fiducial's fit placed, whose part points do not lie on the part that the fit
///   locates, was placed by a look-alike of that fiducial (or the fiducial moved): taken back. Where the part
///   was not found at all, such a scan is not trusted either. A lone scan that the fit located the part from
///   by itself is confirmed by that fit.
PartSelection next_selection(const PartSelection& s, const WorkpieceFit& fit, const PartInputs& in,
                             const WorkpieceFitSettings& wfs) {
    const auto& names = in.fiducial_names;
    PartSelection next = s;
    const auto& regs = *in.registrations;
    auto& ev = *in.evidence;
    bool left_out = false;
    for (std::size_t i = 0; i < regs.size(); ++i) left_out |= s.registered[i] && !s.in_fit[i];
    if (left_out && !fit.valid) {
        std::fill(next.in_fit.begin(), next.in_fit.end(), 1);
        return next;
    }
    const std::size_t registered = count_of(s.registered);
    if (registered == 0 || (registered == 1 && fit.valid)) return next;
    bool any = false;
    for (std::size_t i = 0; i < regs.size(); ++i) {
        if (!s.registered[i] || regs[i].fiducials.size() >= 2 || !ev[i].workpiece_points) continue;
        ev[i].all_normals();
        const auto& wp = *ev[i].workpiece_points;
        const std::string why =
            part_disowns_scan(wp.points_, wp.HasNormals() ? &wp.normals_ : nullptr, fit, *in.reference, wfs);
        if (why.empty()) continue;
        const std::string& name = names[regs[i].fiducials.front()];
        next.registered[i] = 0;
        next.rejected[i] = "only " + name + "'s fit places this scan, and " + why + ": " + name +
                           " moved, or a shape like it elsewhere placed the scan";
        any = true;
    }
    if (!any) return next;
    bool any_in_fit = false;
    for (std::size_t i = 0; i < regs.size(); ++i) any_in_fit |= next.registered[i] && next.in_fit[i];
    if (!any_in_fit) std::fill(next.in_fit.begin(), next.in_fit.end(), 1);
    if (!next.any_registered())
        next.none_left = "no scan could be registered to the machine: the part confirms none of them";
    return next;
}

/// The last stage once more, on every point of the scans in the fit near the reference surfaces: the merge
/// thins the scans, and the part's turn is as uncertain as the noise of the points on its reference faces
/// makes it. With millions of points per scan, every k-th of them.
void refit_on_reference(PartFit& p, const PartInputs& in, const PartSettings& ps) {
    auto& ev = *in.evidence;
    const std::size_t n_scans = ev.size();
    const auto used = [&](std::size_t i) {
        return p.selection.registered[i] && p.selection.in_fit[i] && ev[i].has_points();
    };
    const Eigen::Isometry3d T_nominal_located = p.fit.T_located_nominal.inverse();
    std::size_t total = 0;
    for (std::size_t i = 0; i < n_scans; ++i)
        if (used(i)) total += ev[i].workpiece_points->points_.size();
    const std::size_t stride =
        std::max<std::size_t>(1, (total + ps.reference_points - 1) / ps.reference_points);
    // Each scan's points near the reference surfaces, with their normals; the scans side by side.
    std::vector<std::vector<std::size_t>> near_idx(n_scans);
    tbb::parallel_for(std::size_t(0), n_scans, [&](std::size_t i) {
        if (!used(i)) return;
        const auto& c = *ev[i].workpiece_points;
        const std::size_t n = (c.points_.size() + stride - 1) / stride;
        std::vector<char> near(n, 0);
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 4096), [&](const auto& r) {
            for (std::size_t k = r.begin(); k != r.end(); ++k) {
                double d2 = 0.0;
                const Eigen::Vector3d q = T_nominal_located * c.points_[k * stride];
                near[k] = in.reference->nearest(q, &d2, ps.reference_reach * p.fit.distance) >= 0;
            }
        });
        for (std::size_t k = 0; k < n; ++k)
            if (near[k]) near_idx[i].push_back(k * stride);
        ev[i].normals_at(near_idx[i]);
    });
    std::vector<Eigen::Vector3d> pts, nrm;
    p.on_reference.assign(n_scans, nullptr);
    for (std::size_t i = 0; i < n_scans; ++i) {
        if (!used(i)) continue;
        const auto& c = *ev[i].workpiece_points;
        auto& o = p.on_reference[i] = std::make_shared<open3d::geometry::PointCloud>();
        for (std::size_t k : near_idx[i]) {
            o->points_.push_back(c.points_[k]);
            o->normals_.push_back(c.normals_[k]);
        }
        pts.insert(pts.end(), o->points_.begin(), o->points_.end());
        nrm.insert(nrm.end(), o->normals_.begin(), o->normals_.end());
    }
    const IcpResult r = fit_last_stage(pts, *in.reference, T_nominal_located, p.fit.distance, &nrm);
    if (r.inliers >= p.fit.inliers) {
        p.fit_points = pts.size();
        p.fit.T_located_nominal = r.T_target_source.inverse();
        p.fit.rmse = r.rmse;
        p.fit.inliers = r.inliers;
        p.fit.JtJ = r.JtJ;
    }
}

}  // namespace

void ScanEvidence::normals_at(const std::vector<std::size_t>& idx) {
    if (!workpiece_points || workpiece_points->normals_.size() != workpiece_points->points_.size()) return;
    auto& c = *workpiece_points;
    std::vector<std::size_t> missing;
    for (std::size_t k : idx)
        if (c.normals_[k].squaredNorm() == 0.0) missing.push_back(k);
    if (missing.empty()) return;
    // The neighbour grid is built once: the merge, the lone-scan check and the part's last fit ask in turn.
    if (!grid) grid = std::make_shared<RadiusGrid>(normals_grid(c.points_, normal_radius));
    const auto n = estimate_normals(c.points_, *grid, normal_radius, normal_neighbours, &missing);
    for (std::size_t j = 0; j < missing.size(); ++j)
        c.normals_[missing[j]] = facing(n[j], c.points_[missing[j]], eye);
}

void ScanEvidence::all_normals() {
    if (!workpiece_points) return;
    std::vector<std::size_t> all(workpiece_points->points_.size());
    for (std::size_t k = 0; k < all.size(); ++k) all[k] = k;
    normals_at(all);
}

bool PartSelection::any_registered() const { return count_of(registered) > 0; }

// Only one fiducial's uncorroborated fit placed a scan that puts nothing where the part is: a look-alike of
// that fiducial placed it, or it misses the part, which the fit could not use anyway.
PartSelection first_selection(const PartInputs& in) {
    const auto& names = in.fiducial_names;
    const auto& regs = *in.registrations;
    const auto& ev = *in.evidence;
    const std::size_t n = regs.size();
    PartSelection s;
    s.registered.assign(n, 0);
    s.in_fit.assign(n, 1);
    s.rejected.assign(n, "");
    s.warnings.assign(n, {});
    s.sigma.assign(n, 0.0);
    for (std::size_t i = 0; i < n; ++i) {
        if (!regs[i].valid) continue;
        s.registered[i] = 1;
        if (ev[i].sees_part) continue;
        if (regs[i].fiducials.size() < 2 && !regs[i].corroborated) {
            const std::string& name = names[regs[i].source];
            s.registered[i] = 0;
            s.rejected[i] =
                "only " + name +
                "'s fit places this scan, and it puts nothing of the scan in the "
                "workpiece's region: " +
                name + " moved, or a shape like it elsewhere placed the scan, or the scan misses the part";
        } else {
            s.warnings[i] = "registered, but it shows nothing of the workpiece in its region";
        }
    }
    if (!s.any_registered()) s.none_left = "no scan could be registered to the machine";
    return s;
}

ScanEvidence scan_evidence(const open3d::geometry::PointCloud& points, const Scale& scale,
                           const Eigen::Isometry3d& T_machine0_scan, const Eigen::Vector3d& viewpoint,
                           const Eigen::AlignedBox3d& region, const PartSettings& settings) {
    ScanEvidence e;
    e.scale = scale;
    e.normal_radius = settings.normal_radius * scale.spacing;
    e.normal_neighbours = settings.normal_neighbours;
    auto wp = std::make_shared<open3d::geometry::PointCloud>();
    for (const auto& q : points.points_) {
        const Eigen::Vector3d p = T_machine0_scan * q;
        if (region.contains(p)) wp->points_.push_back(p);
    }
    e.sees_part = wp->points_.size() >= settings.min_region_points;
    if (e.sees_part) {
        wp->normals_.assign(wp->points_.size(), Eigen::Vector3d::Zero());  // none computed yet
        e.eye = T_machine0_scan * viewpoint;
    } else {
        wp->points_.clear();
    }
    e.workpiece_points = wp;
    return e;
}

std::shared_ptr<open3d::geometry::PointCloud> merge_scans(std::vector<ScanEvidence>& evidence,
                                                          const PartSelection& selection, bool fit_only,
                                                          const PartSettings& settings,
                                                          std::vector<int>* scan_of) {
    auto m = std::make_shared<open3d::geometry::PointCloud>();
    std::vector<int> scan;
    const auto taken = [&](std::size_t i) {
        return selection.registered[i] && (!fit_only || selection.in_fit[i]);
    };
    std::size_t total = 0;
    for (std::size_t i = 0; i < evidence.size(); ++i)
        if (taken(i)) total += evidence[i].workpiece_points->points_.size();
    const std::size_t stride =
        std::max<std::size_t>(1, (total + settings.merged_points - 1) / settings.merged_points);
    std::size_t at = 0;  // index into the concatenation, so that the stride runs on across scans
    std::vector<std::vector<std::size_t>> keep(evidence.size());
    for (std::size_t i = 0; i < evidence.size(); ++i) {
        if (!taken(i)) continue;
        const std::size_t n = evidence[i].workpiece_points->points_.size();
        for (std::size_t k = 0; k < n; ++k, ++at)
            if (at % stride == 0) keep[i].push_back(k);
    }
    // The scans' normals side by side: each scan's neighbour grid is built by one thread.
    tbb::parallel_for(std::size_t(0), evidence.size(), [&](std::size_t i) {
        if (taken(i)) evidence[i].normals_at(keep[i]);
    });
    for (std::size_t i = 0; i < evidence.size(); ++i) {
        if (!taken(i)) continue;
        const auto& c = *evidence[i].workpiece_points;
        for (std::size_t k : keep[i]) {
            m->points_.push_back(c.points_[k]);
            if (c.HasNormals()) m->normals_.push_back(c.normals_[k]);
            scan.push_back(static_cast<int>(i));
        }
    }
    if (m->normals_.size() != m->points_.size()) m->normals_.clear();
    if (m->points_.size() > settings.outlier_min_points) {
        const std::vector<std::size_t> kept =
            statistical_inliers(m->points_, settings.outlier_neighbours, settings.outlier_sigmas);
        m = m->SelectByIndex(kept);
        std::vector<int> kept_scan;
        kept_scan.reserve(kept.size());
        for (std::size_t k : kept) kept_scan.push_back(scan[k]);
        scan = std::move(kept_scan);
    }
    if (scan_of) *scan_of = std::move(scan);
    return m;
}

std::vector<ScanOffPart> scans_off_part(const PartFit& p, const PartInputs& in, const PartSettings& ps) {
    std::vector<ScanOffPart> out;
    if (!p.fit.valid || !in.reference) return out;
    auto& ev = *in.evidence;
    const std::size_t n = ev.size();
    std::vector<double> moved(n, -1.0);
    tbb::parallel_for(std::size_t(0), n, [&](std::size_t i) {
        if (!p.selection.registered[i] || !p.selection.in_fit[i] || !ev[i].workpiece_points) return;
        // An even subsample, with normals only where it needs them: the whole scan cost 0.35 s a run of six
        // scans of 250 k points (seed 106), for the same measure.
        const auto& wp = *ev[i].workpiece_points;
        const std::size_t stride =
            std::max<std::size_t>(1, (wp.points_.size() + ps.off_part_points - 1) / ps.off_part_points);
        std::vector<std::size_t> idx;
        for (std::size_t k = 0; k < wp.points_.size(); k += stride) idx.push_back(k);
        ev[i].normals_at(idx);
        std::vector<Eigen::Vector3d> pts, nrm;
        const bool normals = wp.normals_.size() == wp.points_.size();
        for (std::size_t k : idx) {
            pts.push_back(wp.points_[k]);
            if (normals) nrm.push_back(wp.normals_[k]);
        }
        moved[i] = scan_part_offset(pts, normals ? &nrm : nullptr, p.fit, *in.reference, p.settings);
    });
    for (std::size_t i = 0; i < n; ++i)
        if (moved[i] > own_fit_limit_noises * p.settings.noise) out.push_back({i, moved[i]});
    std::stable_sort(out.begin(), out.end(),
                     [](const ScanOffPart& a, const ScanOffPart& b) { return a.moved > b.moved; });
    return out;
}

PartFit fit_part(const PartInputs& in, PartSelection selection, const Config& config) {
    PartFit p;
    const auto& regs = *in.registrations;
    auto& ev = *in.evidence;
    p.selection = std::move(selection);
    std::vector<double> noises;
    for (std::size_t i = 0; i < regs.size(); ++i)
        if (p.selection.registered[i]) noises.push_back(ev[i].scale.noise);
    p.settings = config.workpiece;
    p.settings.noise = median_of(noises);
    p.settings.spacing = in.spacing;
    weigh_registrations(p.selection, in, p.settings.noise, config.part);
    if (!p.selection.none_left.empty()) {
        p.reason = p.selection.none_left;
        return p;
    }
    // The selection depends on the fit, and the fit on the selection: until neither changes.
    for (;;) {
        p.merged = merge_scans(ev, p.selection, true, config.part, &p.merged_scan);
        p.fit = fit_reference_surfaces(p.merged->points_, *in.reference, p.settings,
                                       p.merged->HasNormals() ? &p.merged->normals_ : nullptr);
        PartSelection next = next_selection(p.selection, p.fit, in, p.settings);
        const bool stable = next == p.selection;
        p.selection = std::move(next);
        if (!p.selection.none_left.empty()) {
            p.reason = p.selection.none_left;
            return p;
        }
        if (stable) break;
    }
    p.fit_points = p.merged->points_.size();
    if (p.fit.valid) refit_on_reference(p, in, config.part);
    bool all_in_fit = true;
    for (std::size_t i = 0; i < regs.size(); ++i) {
        if (!p.selection.registered[i] || p.selection.in_fit[i]) continue;
        all_in_fit = false;
        p.selection.warnings[i] = format(
            "left out of the part's fit: its registration leaves the part uncertain by %.3g (1 sigma), more "
            "than %.3g",
            p.selection.sigma[i], p.selection.sigma_limit);
    }
    if (all_in_fit) {
        p.all_registered = p.merged;
        p.all_registered_scan = p.merged_scan;
    } else {
        p.all_registered = merge_scans(ev, p.selection, false, config.part, &p.all_registered_scan);
    }
    p.valid = p.fit.valid;
    p.reason = p.fit.reason;
    return p;
}

}  // namespace partloc
