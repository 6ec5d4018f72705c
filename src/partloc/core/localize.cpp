#include "partloc/core/localize.hpp"

#include <open3d/geometry/KDTreeSearchParam.h>

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <optional>
#include <stdexcept>

#include "partloc/core/icp.hpp"
#include "partloc/core/normals.hpp"
#include "partloc/core/visible_surface.hpp"

namespace partloc {

namespace {

std::string fmt(const char* f, double a, double b = 0, double c = 0) {
    char buf[200];
    std::snprintf(buf, sizeof buf, f, a, b, c);
    return buf;
}

std::vector<Eigen::Vector3d> normalized(std::vector<Eigen::Vector3d> v) {
    for (auto& n : v) n.normalize();
    return v;
}

}  // namespace

PreparedScan prepare_scan(const open3d::geometry::PointCloud& points, const Scale& scale, double sampling,
                          const Eigen::Vector3d& viewpoint) {
    PreparedScan s;
    s.scale = scale;
    s.viewpoint = viewpoint;
    s.cloud = std::make_shared<open3d::geometry::PointCloud>();
    s.cloud->points_ = points.points_;
    // The grids answer balls of a fiducial's radius and two samplings more (about 14 samplings): cells of two
    // samplings were the fastest to build and to ask (docs/history.md).
    const double grid_cell = 2.0 * sampling;
    s.grid = std::make_shared<RadiusGrid>(s.cloud->points_, grid_cell);
    s.fit_normals = std::make_shared<PreparedScan::PointNormals>();
    // The screening takes at most 1500 points of the thousands around a candidate: a quarter of the scan
    // serves (the points around a fiducial in a scan of 250 k points number 10-50 thousand).
    s.sparse_stride = s.cloud->points_.size() > 40000 ? 4 : 1;
    if (s.sparse_stride > 1) {
        s.sparse = std::make_shared<open3d::geometry::PointCloud>();
        s.sparse->points_.reserve(s.cloud->points_.size() / s.sparse_stride + 1);
        for (std::size_t i = 0; i < s.cloud->points_.size(); i += s.sparse_stride)
            s.sparse->points_.push_back(s.cloud->points_[i]);
        s.sparse_grid = std::make_shared<RadiusGrid>(s.sparse->points_, grid_cell);
    } else {
        s.sparse = s.cloud;
        s.sparse_grid = s.grid;
    }
    // The global fit's points: one per cube of the sampling, each with the normal of the points within the
    // cube of twice the sampling around it, from sums kept per cube (voxel_normals: a tenth of the time of a
    // neighbour search per point, and more scans right; docs/history.md).
    OrientedSample coarse = voxel_normals(s.cloud->points_, sampling, s.viewpoint);
    s.coarse_points = std::move(coarse.points);
    s.coarse_normals = std::move(coarse.normals);
    return s;
}

namespace {

/// The samples of `mesh` that can be seen from outside it; all of them when none can (a mesh that hides
/// everything is not a solid's surface, and is left to the fit as it is).
std::shared_ptr<open3d::geometry::PointCloud> visible_part(
    std::shared_ptr<open3d::geometry::PointCloud> samples, const open3d::geometry::TriangleMesh& mesh) {
    const std::vector<char> visible = visible_from_outside(mesh, samples->points_, samples->normals_);
    if (std::find(visible.begin(), visible.end(), 1) == visible.end()) return samples;
    if (std::find(visible.begin(), visible.end(), 0) == visible.end()) return samples;
    auto kept = std::make_shared<open3d::geometry::PointCloud>();
    for (std::size_t i = 0; i < visible.size(); ++i) {
        if (!visible[i]) continue;
        kept->points_.push_back(samples->points_[i]);
        kept->normals_.push_back(samples->normals_[i]);
    }
    return kept;
}

/// The model's samples `spacing` apart, with normals as they come (not yet of unit length): a mesh's visible
/// samples, or the points as they are (their normals estimated when they have none).
std::shared_ptr<open3d::geometry::PointCloud> model_samples(const std::string& name,
                                                            const open3d::geometry::TriangleMesh* mesh,
                                                            const open3d::geometry::PointCloud* points,
                                                            double spacing) {
    // What a scanner can see of a mesh: samples on faces inside the solid are dropped (visible_surface.hpp).
    if (mesh && !mesh->triangles_.empty()) return visible_part(sample_mesh(*mesh, spacing), *mesh);
    if (!points || points->points_.empty())
        throw std::invalid_argument(name + ": model has neither triangles nor points");
    auto dense = std::make_shared<open3d::geometry::PointCloud>();
    dense->points_ = points->points_;
    if (points->HasNormals()) {
        dense->normals_ = points->normals_;
    } else {
        // A point model without normals: estimate them and orient them consistently (outward is then a
        // guess; the fit uses them only up to sign).
        dense->EstimateNormals(open3d::geometry::KDTreeSearchParamKNN(20));
        dense->OrientNormalsConsistentTangentPlane(12);
    }
    return dense;
}

}  // namespace

Surface model_surface(const std::string& name, const open3d::geometry::TriangleMesh* mesh,
                      const open3d::geometry::PointCloud* points, double spacing) {
    std::shared_ptr<open3d::geometry::PointCloud> samples = model_samples(name, mesh, points, spacing);
    samples->normals_ = normalized(samples->normals_);
    return make_surface(samples, spacing);
}

PreparedModel prepare_model(const std::string& name, const open3d::geometry::TriangleMesh* mesh,
                            const open3d::geometry::PointCloud* points, double dense_spacing,
                            double sampling) {
    PreparedModel m;
    m.name = name;
    m.sampling = sampling;
    std::shared_ptr<open3d::geometry::PointCloud> dense = model_samples(name, mesh, points, dense_spacing);
    // A mesh is sampled again at the PPF sampling; points are thinned to it (normals averaged as they come).
    std::shared_ptr<open3d::geometry::PointCloud> coarse = mesh && !mesh->triangles_.empty()
                                                               ? model_samples(name, mesh, points, sampling)
                                                               : dense->VoxelDownSample(sampling);
    dense->normals_ = normalized(dense->normals_);
    coarse->normals_ = normalized(coarse->normals_);
    m.dense = make_surface(dense, dense_spacing);
    // For the screening of the global fit's candidates (its stages at 2 and 1 sampling).
    const double cell = std::max(dense_spacing, 0.25 * sampling);
    add_coarse_map(m.dense, cell, 2.0 * sampling + cell);
    PpfSettings ps;
    ps.sampling = sampling;
    m.ppf = std::make_shared<PpfModel>(coarse->points_, coarse->normals_, ps);
    m.symmetry = find_symmetry(m.dense);
    return m;
}

double support(const FiducialFit& f) { return static_cast<double>(f.inliers) * f.score; }

VerifySettings verify_settings(const PreparedScan& scan, const PreparedModel& model) {
    VerifySettings vs;
    const double noise = std::max(scan.scale.noise, 1e-9), ms = model.dense.spacing;
    vs.inlier_distance = std::sqrt(9.0 * noise * noise + 0.5 * ms * ms);
    vs.bin_size = 2.0 * std::max(ms, scan.scale.spacing);
    return vs;
}

namespace {

struct Thresholds {
    VerifySettings vs;
    IcpSettings is;
    double noise;
};

Thresholds thresholds(const PreparedScan& scan, const PreparedModel& model) {
    Thresholds t;
    const double s = model.sampling;
    t.noise = std::max(scan.scale.noise, 1e-9);
    t.vs = verify_settings(scan, model);
    t.is.max_distances = {2.0 * s, 1.0 * s, 0.5 * s, std::max(t.vs.inlier_distance, 0.2 * s)};
    return t;
}

/// The cloud's points within `radius` of `centre`, by ascending index; their indices too when `indices` is
/// not null.
std::vector<Eigen::Vector3d> points_near(const open3d::geometry::PointCloud& cloud, const RadiusGrid& grid,
                                         const Eigen::Vector3d& centre, double radius,
                                         std::vector<int>* indices = nullptr) {
    std::vector<int> own;
    std::vector<int>& idx = indices ? *indices : own;
    grid.within(centre, radius, idx);  // ascending: the result must not vary
    std::vector<Eigen::Vector3d> out;
    out.reserve(idx.size());
    for (int k : idx) out.push_back(cloud.points_[k]);
    return out;
}

std::vector<Eigen::Vector3d> points_near(const PreparedScan& scan, const Eigen::Vector3d& centre,
                                         double radius) {
    return points_near(*scan.cloud, *scan.grid, centre, radius);
}

/// Normals (either sign) of the scan's points `idx`, from the fit_normals kept on the scan, computing those
/// not yet there from their neighbours among `around` (the scan's points `around_idx`, ascending), which
/// must hold every scan point within the normals' radius of each point asked for.
std::vector<Eigen::Vector3d> fit_normals_of(const PreparedScan& scan, const std::vector<int>& idx,
                                            const std::vector<Eigen::Vector3d>& around,
                                            const std::vector<int>& around_idx) {
    auto& kept = *scan.fit_normals;
    std::vector<std::size_t> missing;  // positions in `around`
    for (int k : idx)
        if (kept.at.find(static_cast<cells::Key>(k)) == cells::kNone)
            missing.push_back(std::lower_bound(around_idx.begin(), around_idx.end(), k) - around_idx.begin());
    if (!missing.empty()) {
        const auto n = around.size() < 3
                           ? std::vector<Eigen::Vector3d>(missing.size(), Eigen::Vector3d::UnitZ())
                           : estimate_normals(around, 3.0 * scan.scale.spacing, 20, &missing);
        for (std::size_t j = 0; j < missing.size(); ++j) {
            kept.at.add(static_cast<cells::Key>(around_idx[missing[j]]),
                        static_cast<std::uint32_t>(kept.normals.size()));
            kept.normals.push_back(n[j]);
        }
    }
    std::vector<Eigen::Vector3d> out;
    out.reserve(idx.size());
    for (int k : idx) out.push_back(kept.normals[kept.at.find(static_cast<cells::Key>(k))]);
    return out;
}

/// Whether the point p (the points' frame) lies within `distance` of the surface.
bool near_surface(const Surface& surface, const Eigen::Isometry3d& T_surface_pts, const Eigen::Vector3d& p,
                  double distance) {
    double d2 = 0.0;
    return surface.nearest(T_surface_pts * p, &d2, distance) >= 0;
}

std::vector<Eigen::Vector3d> points_near_surface(const std::vector<Eigen::Vector3d>& pts,
                                                 const Surface& surface,
                                                 const Eigen::Isometry3d& T_surface_pts, double distance) {
    std::vector<Eigen::Vector3d> out;
    out.reserve(pts.size());
    for (const auto& p : pts)
        if (near_surface(surface, T_surface_pts, p, distance)) out.push_back(p);
    return out;
}

std::vector<Eigen::Vector3d> subsample(const std::vector<Eigen::Vector3d>& v, std::size_t max_n) {
    std::vector<Eigen::Vector3d> out;
    const std::size_t stride = std::max<std::size_t>(1, (v.size() + max_n - 1) / max_n);
    for (std::size_t k = 0; k < v.size(); k += stride) out.push_back(v[k]);
    return out;
}

FiducialFit judge(const PreparedModel& model, const Eigen::Isometry3d& T_scan_model, const Verification& v,
                  const Thresholds& t, const LocalizeSettings& st) {
    FiducialFit f;
    f.fiducial = model.name;
    f.T_scan_fiducial = T_scan_model;
    f.rmse = v.rmse;
    f.coverage = v.coverage;
    f.violation = v.violation;
    f.conditioning = v.conditioning;
    f.spread = v.spread;
    f.inliers = v.inliers;
    f.overflow = v.inliers ? static_cast<double>(v.overflow) / v.inliers : 0.0;
    f.observed = v.observed;
    f.seen_through = v.seen_through + v.crowded;
    f.JtJ = v.JtJ;
    f.JtJ_facing = v.JtJ_facing;
    f.weakest_observed = v.weakest_observed;
    f.weakest_against = v.weakest_against;
    f.score = v.coverage * (1.0 - v.violation);
    if (v.inliers < st.min_inliers)
        f.reason = fmt("too few points on the fiducial (%.0f, needs %.0f)", v.inliers, st.min_inliers);
    else if (v.conditioning < st.min_conditioning)
        f.reason =
            fmt("seen only as a plane or an edge: the fit leaves a direction free (conditioning %.4f, "
                "needs %.3f)",
                v.conditioning, st.min_conditioning);
    else if (v.violation > st.max_violation)
        f.reason =
            fmt("the scan contradicts %.0f%% of the fiducial's surface: seen through it or material "
                "just in front of it (at most %.0f%%)",
                100 * v.violation, 100 * st.max_violation);
    else if (f.overflow > st.max_overflow)
        f.reason =
            fmt("the scanned surfaces run on past the fiducial's edges (%.0f%% of its points; at most "
                "%.0f%%): something larger is there",
                100 * f.overflow, 100 * st.max_overflow);
    else if (v.coverage < st.min_coverage)
        f.reason = fmt("only %.0f%% of the fiducial's visible surface observed (needs %.0f%%)",
                       100 * v.coverage, 100 * st.min_coverage);
    else if (v.rmse > st.max_rmse * t.vs.inlier_distance)
        f.reason = fmt("residual %.4g is above %.4g", v.rmse, st.max_rmse * t.vs.inlier_distance);
    f.valid = f.reason.empty();
    return f;
}

}  // namespace

std::string slide_refutation(const FiducialFit& f, const LocalizeSettings& st) {
    const auto against = static_cast<double>(f.weakest_against);
    const auto seen = static_cast<double>(f.weakest_observed + f.weakest_against);
    if (f.weakest_against < st.min_weakest_against || against <= st.max_weakest_against * seen) return "";
    return fmt(
        "slides: the scan contradicts the faces that hold its least held direction (%.0f of %.0f of "
        "their views; at most %.0f%%)",
        against, seen, 100 * st.max_weakest_against);
}

FiducialFit evaluate_model(const PreparedScan& scan, const PreparedModel& model,
                           const Eigen::Isometry3d& T_scan_model, const LocalizeSettings& st) {
    const Thresholds t = thresholds(scan, model);
    const auto local = points_near(scan, T_scan_model * model.dense.center,
                                   model.dense.diameter / 2.0 + 2.0 * model.sampling);
    const Verification v = verify_pose(local, model.dense, T_scan_model.inverse(), scan.viewpoint, t.vs);
    return judge(model, T_scan_model, v, t, st);
}

std::vector<FiducialFit> fit_candidates(const PreparedScan& scan, const PreparedModel& model,
                                        const LocalizeSettings& st) {
    return fit_candidates(scan, model, st, ppf_detect(*model.ppf, scan.coarse_points, scan.coarse_normals));
}

std::vector<FiducialFit> fit_candidates(const PreparedScan& scan, const PreparedModel& model,
                                        const LocalizeSettings& st,
                                        const std::vector<PoseCandidate>& candidates) {
    const Thresholds t = thresholds(scan, model);
    const double s = model.sampling;

    // Stage 1, screening: every candidate gets a coarse fit on a few thousand points and is ranked by the
    // points it then explains. Stage 2: the best few get the fine fit and the full verification.
    struct Screened {
        Eigen::Isometry3d T_model_scan;
        Eigen::Vector3d centre;  ///< of the points around the candidate (scan frame)
        double support = 0.0;
        double against = 0.0;  ///< the quick verification's evidence against, per its limit (the larger)
        bool passed() const { return against <= 2.0; }
    };
    std::vector<Screened> screened;
    IcpSettings coarse = t.is;
    coarse.max_distances = {2.0 * s, 1.0 * s};
    coarse.max_iterations = 10;
    coarse.approximate_from = s;  // both stages: a candidate is degrees off (nearest_map.hpp)
    VerifySettings quick = t.vs;
    quick.inlier_distance = std::max(t.vs.inlier_distance, 0.25 * s);  // before the fine fit
    const double radius = model.dense.diameter / 2.0 + 2.0 * s;
    // Every candidate the global fit returns (at most PpfSettings::max_candidates) is screened.
    const int n = static_cast<int>(candidates.size());
    for (int i = 0; i < n; ++i) {
        const Eigen::Isometry3d& T_sm = candidates[i].T_scene_model;
        Screened c;
        c.centre = T_sm * model.dense.center;
        // The points around the candidate, from the sparse copy unless that leaves fewer than the subsample.
        std::vector<Eigen::Vector3d> local = points_near(*scan.sparse, *scan.sparse_grid, c.centre, radius);
        std::size_t local_count = local.size() * scan.sparse_stride;
        if (scan.sparse_stride > 1 && local.size() < st.screen_points) {
            local = points_near(scan, c.centre, radius);
            local_count = local.size();
        }
        if (local_count < st.min_inliers) continue;
        const auto sub = subsample(local, st.screen_points);
        const IcpResult icp = icp_point_to_plane(sub, model.dense, T_sm.inverse(), coarse);
        c.T_model_scan = icp.T_target_source;
        // Candidates that the coarse fit brought to one pose are one candidate.
        bool duplicate = false;
        for (const auto& o : screened) {
            const PoseError e = pose_error(o.T_model_scan, c.T_model_scan);
            duplicate = duplicate || (e.translation < 0.5 * s && e.rotation_deg < 3.0);
        }
        if (duplicate) continue;
        // A quick verification on the subsample ranks the candidates: support alone would favour a model
        // lying on a large plane over the real, smaller instance.
        // Ray bins as wide as the subsample's spacing, so that a bin of observed surface holds a point as it
        // does at full density (with the full bins, coverage on 1500 points was about 0.3 for every
        // candidate, right or wrong, and could not rank them).
        VerifySettings q = quick;
        q.bin_size =
            quick.bin_size *
            std::sqrt(std::max(1.0, static_cast<double>(local_count) / static_cast<double>(sub.size())));
        const Verification v = verify_pose(sub, model.dense, c.T_model_scan, scan.viewpoint, q);
        const FiducialFit f = judge(model, c.T_model_scan.inverse(), v, t, st);
        // Evidence against a pose counts against it in the ranking too, not only past a threshold.
        const double against = std::max(f.violation / st.max_violation, f.overflow / st.max_overflow);
        c.support = support(f) * std::max(0.0, 1.0 - 0.5 * against);
        c.against = against;
        screened.push_back(std::move(c));
    }
    std::stable_sort(screened.begin(), screened.end(), [](const Screened& a, const Screened& b) {
        if (a.passed() != b.passed()) return a.passed();
        return a.support > b.support;
    });
    IcpSettings fine = t.is;
    fine.max_distances = {0.5 * s, 0.25 * s};
    fine.max_iterations = 15;
    fine.min_step = 1e-5;
    IcpSettings polish = t.is;
    polish.max_distances = {t.is.max_distances.back()};
    // The polish places one fiducial, which the scan's joint fit refines; a step of 1e-4 (0.006 degrees, or
    // 0.008 mm on a block of 80 mm) ends it in about half the iterations that 1e-5 takes (seed 106: 0.64 s
    // against 0.92 s for 36 polishes).
    polish.min_step = 1e-4;
    // One candidate's fine fit from T_start (model <- scan), its polish, verification and judgement.
    const auto refine = [&](const std::vector<Eigen::Vector3d>& local_all, const Eigen::Isometry3d& T_start) {
        // Down to a quarter of the sampling on a subsample, then every point at the noise's scale: a face
        // seen with few points (a narrow wall) is what fixes some directions, and a subsample thins it.
        const IcpResult icp =
            icp_point_to_plane(subsample(local_all, st.fine_points), model.dense, T_start, fine);
        // The polish sees only the points near the surface after the fine fit (the rest cannot become
        // correspondences within the polish distance unless the pose moves by more than the fit's step), of
        // at most st.polish_points around the candidate, taken by their order: it places one fiducial, which
        // the scan's joint fit then refines on every point, and all of them cost 6.5 of 20 s on six scans of
        // 2 M points (seed 106; 0.53 s at 250 k).
        const auto near =
            points_near_surface(subsample(local_all, st.polish_points), model.dense, icp.T_target_source,
                                2.0 * polish.max_distances.back() + 0.1 * s);
        const IcpResult last = icp_point_to_plane(near, model.dense, icp.T_target_source, polish);
        const Eigen::Isometry3d T_ms = last.T_target_source;
        // Verify on the points around the refined pose: the fit may have moved by up to the sampling.
        const auto local = points_near(scan, T_ms.inverse() * model.dense.center, radius);
        const Verification v = verify_pose(local, model.dense, T_ms, scan.viewpoint, t.vs);
        FiducialFit f = judge(model, T_ms.inverse(), v, t, st);
        // A fit's own optimum, not a pose others set (evaluate_model): one slid along its least held
        // direction onto the clutter beside it is refuted by the faces that hold that direction.
        if (f.valid) {
            f.reason = slide_refutation(f, st);
            f.valid = f.reason.empty();
        }
        return f;
    };
    // A fit is a true optimum only if it is one along the direction its data hold least (issue 25: fits
    // slid 1.2-3.6 mm along a narrow face's normal, rotation right, passed every check). From the fit moved
    // by one and two samplings each way along that direction the fit is made again: a pose that explains
    // more of the scan replaces it; one as good as it but apart leaves the direction undecided (rejected).
    const auto settle_slides = [&](FiducialFit first, const std::vector<Eigen::Vector3d>& local_all) {
        const double L = 0.5 * model.dense.diameter;
        const Matrix6d S = centred_scaled(model.dense.center, L);
        const Eigen::SelfAdjointEigenSolver<Matrix6d> es(S * first.JtJ * S.transpose());
        const Vector6d weakest = es.eigenvectors().col(0);
        std::optional<FiducialFit> rival;  // the best valid fit apart from the first
        double apart = 0.0;                // its distance from the first
        for (int k = 1; k <= st.slide_restarts; ++k)
            for (const double sign : {1.0, -1.0}) {
                const Vector6d step = sign * k * s * weakest;
                const Eigen::Isometry3d start =
                    motion_about(step, model.dense.center, L) * first.T_scan_fiducial.inverse();
                FiducialFit r = refine(local_all, start);
                if (!r.valid) continue;
                const PoseError e = pose_error(r.T_scan_fiducial, first.T_scan_fiducial);
                if (e.translation < st.slide_distance * s && e.rotation_deg < st.slide_angle_deg) continue;
                if (!rival || support(r) > support(*rival)) {
                    rival = std::move(r);
                    apart = e.translation;
                }
            }
        if (!rival) return first;
        // The better pose, unless the other explains the scan about as well.
        if (support(*rival) > support(first)) std::swap(first, *rival);
        if (support(*rival) >= st.slide_tie * support(first)) {
            first.valid = false;
            first.reason =
                fmt("slides: two poses %.3g apart along its least held direction fit about equally "
                    "well (%.0f%% of the support)",
                    apart, 100.0 * support(*rival) / support(first));
        }
        return first;
    };
    std::vector<FiducialFit> fits;
    for (std::size_t i = 0; i < screened.size() && static_cast<int>(i) < st.verified; ++i) {
        const auto& c = screened[i];
        // Past the first, a candidate whose quick verification found five times the evidence against that a
        // fit may have is not fitted finely: of 570 candidates verified in the first ten cells of seeds
        // 1500-1519 (git show 52c5702:bench/results/candidates_gate_1500.txt), the 107 accepted had at
        // most 3.3 times before their fine fit; 96 others past the first had more than 5. The first stays, so
        // that a fiducial's reason in the report is its best candidate's.
        if (i > 0 && c.against > 5.0) continue;
        const auto local_all = points_near(scan, c.centre, radius);
        FiducialFit f = refine(local_all, c.T_model_scan);
        if (f.valid && st.slide_restarts > 0) f = settle_slides(std::move(f), local_all);
        f.candidates = n;
        fits.push_back(std::move(f));
    }
    std::stable_sort(fits.begin(), fits.end(), [](const FiducialFit& a, const FiducialFit& b) {
        if (a.valid != b.valid) return a.valid;
        return support(a) > support(b);
    });
    return fits;
}

Surface make_pose_target(const std::vector<const PreparedModel*>& models,
                         const std::vector<Eigen::Isometry3d>& T_machine_model) {
    std::vector<const Surface*> parts;
    for (const PreparedModel* m : models) parts.push_back(&m->dense);
    parts.resize(std::min(parts.size(), T_machine_model.size()));
    return compose_surfaces(parts, {T_machine_model.begin(), T_machine_model.begin() + parts.size()});
}

ScanPoseFit fit_scan_pose(const PreparedScan& scan, const std::vector<const PreparedModel*>& models,
                          const std::vector<Eigen::Isometry3d>& T_machine_model,
                          const Eigen::Isometry3d& init, const LocalizeSettings& st, double start_distance,
                          const Surface* target, std::size_t max_points_per_model) {
    ScanPoseFit out;
    out.T_machine_scan = init;
    if (models.empty() || models.size() != T_machine_model.size()) return out;
    // Every fiducial's samples in the machine frame make one surface; the points near each (at the first
    // guess) are the source. One least-squares fit then weighs each fiducial by what the scan saw of it.
    std::vector<Eigen::Vector3d> source, source_normals;
    double inlier = 0.0, start = 0.0;
    for (std::size_t g = 0; g < models.size(); ++g) {
        const PreparedModel& m = *models[g];
        const Thresholds t = thresholds(scan, m);
        inlier = std::max(inlier, t.vs.inlier_distance);
        start = std::max(start, std::max(t.vs.inlier_distance, 0.25 * m.sampling));
        const Eigen::Isometry3d& F = T_machine_model[g];
        const Eigen::Isometry3d T_scan_model = init.inverse() * F;
        // The points around the fiducial; their normals come from all of them: the ball reaches two samplings
        // past the fiducial, the normals' radius (three spacings) is at most 1.2 samplings, and the points
        // taken lie within twice the first stage's distance of its surface (so only those at its far corners,
        // in the hypotheses' fits, can miss a neighbour).
        std::vector<int> local_idx;
        const auto local = points_near(*scan.cloud, *scan.grid, T_scan_model * m.dense.center,
                                       m.dense.diameter / 2.0 + 2.0 * m.sampling, &local_idx);
        std::vector<int> near;  // indices of the scan's points
        const Eigen::Isometry3d T_model_scan = T_scan_model.inverse();
        const double distance = 2.0 * std::max(start, start_distance);
        for (std::size_t j = 0; j < local.size(); ++j)
            if (near_surface(m.dense, T_model_scan, local[j], distance)) near.push_back(local_idx[j]);
        // The points' own normals keep a narrow face's plane from taking the points of the faces beside it
        // (those lie within the correspondence distance of its plane near the edge, all on one side): on
        // a weakly held direction that bias reached 0.3 mm (seed 3, scan 3), 0.003 mm with the check.
        if (max_points_per_model > 0 && near.size() > max_points_per_model) {
            // Every k-th, by the scan's order.
            const std::size_t k = (near.size() + max_points_per_model - 1) / max_points_per_model;
            std::vector<int> keep;
            for (std::size_t i = 0; i < near.size(); i += k) keep.push_back(near[i]);
            near.swap(keep);
        }
        for (int k : near) source.push_back(scan.cloud->points_[k]);
        const auto nn = fit_normals_of(scan, near, local, local_idx);
        source_normals.insert(source_normals.end(), nn.begin(), nn.end());
        out.points.push_back(near.size());
    }
    std::optional<Surface> built;
    if (!target) built.emplace(make_pose_target(models, T_machine_model));
    const Surface& all = target ? *target : *built;
    IcpSettings is;
    // From a start that is already close (start_distance 0: the scan's joint fit, from the winning
    // hypothesis's fit) the last stage alone. Seed 106's joint fits took 27 iterations on every point in
    // their twelve stages (two each); without the first stage the part moved by 3e-5 mm.
    is.max_distances = {inlier};
    if (start_distance > 0) is.max_distances.insert(is.max_distances.begin(), start);
    if (start_distance > start) is.max_distances.insert(is.max_distances.begin(), start_distance);
    const IcpResult icp = icp_point_to_plane(source, all, init, is, &source_normals);
    if (icp.inliers < st.min_inliers) return out;
    out.valid = true;
    out.T_machine_scan = icp.T_target_source;
    out.JtJ = icp.JtJ;
    // Each fiducial's share, on its own points at the result (the same distance as the last stage).
    std::size_t first = 0;
    const Eigen::Vector3d eye = out.T_machine_scan * scan.viewpoint;
    const double facing_cos = VerifySettings{}.facing_cos;
    Matrix6d edge_on = Matrix6d::Zero();  // summed over the few points seen edge-on (verify.cpp)
    for (std::size_t g = 0; g < models.size(); ++g) {
        Matrix6d H = Matrix6d::Zero();
        for (std::size_t i = first; i < first + out.points[g]; ++i) {
            const Eigen::Vector3d p = out.T_machine_scan * source[i];
            double d2 = 0.0;
            const int k = all.nearest(p, &d2, inlier);
            if (k < 0) continue;
            Vector6d J;
            J << p.cross(all.normals[k]), all.normals[k];
            H += J * J.transpose();
            const Eigen::Vector3d to_eye = eye - p;
            const double along_n = to_eye.dot(all.normals[k]);
            if (along_n * along_n < facing_cos * facing_cos * to_eye.squaredNorm())
                edge_on += J * J.transpose();
        }
        out.JtJ_per_model.push_back(H);
        out.JtJ_facing += H;
        first += out.points[g];
    }
    out.JtJ_facing -= edge_on;
    out.rmse = icp.rmse;
    out.inliers = icp.inliers;
    out.inlier_distance = inlier;
    out.source = std::move(source);
    out.source_normals = std::move(source_normals);
    return out;
}

FiducialFit localize_model(const PreparedScan& scan, const PreparedModel& model, const LocalizeSettings& st) {
    const auto fits = fit_candidates(scan, model, st);
    if (fits.empty()) {
        FiducialFit none;
        none.fiducial = model.name;
        none.reason = "no candidate pose: the scan has no geometry like this fiducial near enough points";
        return none;
    }
    FiducialFit best = fits.front();  // accepted ones first, then by support
    if (!best.valid) return best;
    for (std::size_t i = 1; i < fits.size(); ++i) {
        const auto& f = fits[i];
        if (!f.valid) continue;
        const PoseError e = pose_error(f.T_scan_fiducial, best.T_scan_fiducial);
        if ((e.translation > 2.0 * model.dense.spacing || e.rotation_deg > 2.0) &&
            support(f) >= st.ambiguity * support(best)) {
            best.valid = false;
            best.reason =
                fmt("ambiguous: two poses %.3g apart fit about equally well (%.0f%% of the support)",
                    e.translation, 100.0 * support(f) / support(best));
            break;
        }
    }
    return best;
}

}  // namespace partloc
