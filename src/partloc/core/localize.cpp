#include "partloc/core/localize.hpp"

#include <open3d/geometry/KDTreeSearchParam.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <stdexcept>

#include "partloc/core/icp.hpp"

namespace partloc {

namespace {

std::string fmt(const char* f, double a, double b = 0) {
    char buf[160];
    std::snprintf(buf, sizeof buf, f, a, b);
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
    // Normals from about 30 neighbours at the scan's own spacing; the scanner looks from the viewpoint, so
    // every surface it saw faces it.
    s.cloud->EstimateNormals(open3d::geometry::KDTreeSearchParamHybrid(3.5 * scale.spacing, 30));
    s.cloud->OrientNormalsTowardsCameraLocation(s.viewpoint);
    s.tree = std::make_shared<open3d::geometry::KDTreeFlann>(*s.cloud);
    const auto coarse = s.cloud->VoxelDownSample(sampling);
    s.coarse_points = coarse->points_;
    s.coarse_normals = normalized(coarse->normals_);
    return s;
}

PreparedModel prepare_model(const std::string& name, const open3d::geometry::TriangleMesh* mesh,
                            const open3d::geometry::PointCloud* points, double dense_spacing, double sampling) {
    PreparedModel m;
    m.name = name;
    m.sampling = sampling;
    std::shared_ptr<open3d::geometry::PointCloud> dense, coarse;
    if (mesh && !mesh->triangles_.empty()) {
        dense = sample_mesh(*mesh, dense_spacing);
        coarse = sample_mesh(*mesh, sampling);
    } else if (points && !points->points_.empty()) {
        dense = std::make_shared<open3d::geometry::PointCloud>();
        dense->points_ = points->points_;
        if (points->HasNormals()) {
            dense->normals_ = points->normals_;
        } else {
            // A point model without normals: estimate them and orient them consistently (outward is then
            // a guess; the fit uses them only up to sign).
            dense->EstimateNormals(open3d::geometry::KDTreeSearchParamKNN(20));
            dense->OrientNormalsConsistentTangentPlane(12);
        }
        coarse = dense->VoxelDownSample(sampling);
    } else {
        throw std::invalid_argument(name + ": model has neither triangles nor points");
    }
    dense->normals_ = normalized(dense->normals_);
    coarse->normals_ = normalized(coarse->normals_);
    m.dense = make_surface(dense, dense_spacing);
    PpfSettings ps;
    ps.sampling = sampling;
    m.ppf = std::make_shared<PpfModel>(coarse->points_, coarse->normals_, ps);
    return m;
}

FiducialFit localize_model(const PreparedScan& scan, const PreparedModel& model, const LocalizeSettings& st) {
    FiducialFit best;
    best.fiducial = model.name;
    const double s = model.sampling;
    const double noise = std::max(scan.scale.noise, 1e-9);
    const double ms = model.dense.spacing;
    VerifySettings vs;
    vs.inlier_distance = std::sqrt(9.0 * noise * noise + 0.5 * ms * ms);
    vs.cover_distance = std::max(vs.inlier_distance, 1.5 * scan.scale.spacing);
    IcpSettings is;
    is.max_distances = {2.0 * s, 1.0 * s, 0.5 * s, std::max(vs.inlier_distance, 0.2 * s)};

    const auto candidates = ppf_detect(*model.ppf, scan.coarse_points, scan.coarse_normals);
    if (candidates.empty()) {
        best.reason = "no candidate pose: the scan has no geometry like this fiducial";
        return best;
    }

    struct Tried {
        FiducialFit fit;
        Verification v;
    };
    std::vector<Tried> tried;
    const double radius = model.dense.diameter / 2.0 + 2.0 * s;
    auto subsample = [](const std::vector<Eigen::Vector3d>& v, std::size_t max_n) {
        std::vector<Eigen::Vector3d> out;
        const std::size_t stride = std::max<std::size_t>(1, (v.size() + max_n - 1) / max_n);
        for (std::size_t k = 0; k < v.size(); k += stride) out.push_back(v[k]);
        return out;
    };

    // Stage 1, screening: every candidate gets a coarse fit on a few thousand points and is ranked by the
    // points it then explains. Stage 2: the best few get the fine fit and the full verification.
    struct Screened {
        Eigen::Isometry3d T_model_scan;
        std::vector<Eigen::Vector3d> local;
        std::size_t support = 0;
    };
    std::vector<Screened> screened;
    IcpSettings coarse = is;
    coarse.max_distances = {2.0 * s, 1.0 * s};
    coarse.max_iterations = 15;
    const int n = std::min<int>(st.candidates, static_cast<int>(candidates.size()));
    std::vector<int> idx;
    std::vector<double> d2;
    for (int i = 0; i < n; ++i) {
        const Eigen::Isometry3d& T_sm = candidates[i].T_scene_model;
        scan.tree->SearchRadius(T_sm * model.dense.center, radius, idx, d2);
        if (idx.size() < st.min_inliers) continue;
        std::sort(idx.begin(), idx.end());  // the tree's order is not guaranteed; the result must not vary
        Screened c;
        c.local.reserve(idx.size());
        for (int k : idx) c.local.push_back(scan.cloud->points_[k]);
        const auto sub = subsample(c.local, 3000);
        const IcpResult icp = icp_point_to_plane(sub, model.dense, T_sm.inverse(), coarse);
        c.T_model_scan = icp.T_target_source;
        c.support = icp.inliers;
        // Candidates that the coarse fit brought to one pose are one candidate.
        bool duplicate = false;
        for (const auto& o : screened) {
            const PoseError e = pose_error(o.T_model_scan, c.T_model_scan);
            duplicate = duplicate || (e.translation < 0.5 * s && e.rotation_deg < 3.0);
        }
        if (!duplicate) screened.push_back(std::move(c));
    }
    std::stable_sort(screened.begin(), screened.end(),
                     [](const Screened& a, const Screened& b) { return a.support > b.support; });
    IcpSettings fine = is;
    fine.max_distances = {0.5 * s, is.max_distances.back()};
    for (std::size_t i = 0; i < screened.size() && static_cast<int>(i) < st.verified; ++i) {
        const auto& c = screened[i];
        const IcpResult icp = icp_point_to_plane(subsample(c.local, 20000), model.dense, c.T_model_scan, fine);
        const Eigen::Isometry3d T_ms = icp.T_target_source;
        const Verification v = verify_pose(c.local, model.dense, T_ms, scan.viewpoint, vs);
        Tried t;
        t.v = v;
        FiducialFit& f = t.fit;
        f.fiducial = model.name;
        f.T_scan_fiducial = T_ms.inverse();
        f.rmse = v.rmse;
        f.coverage = v.coverage;
        f.violation = v.violation;
        f.conditioning = v.conditioning;
        f.inliers = v.inliers;
        f.JtJ = v.JtJ;
        f.score = v.coverage * (1.0 - v.violation);
        if (v.inliers < st.min_inliers)
            f.reason = fmt("too few points on the fiducial (%.0f, needs %.0f)", v.inliers, st.min_inliers);
        else if (v.conditioning < st.min_conditioning)
            f.reason = fmt("seen only as a plane or an edge: the fit leaves a direction free (conditioning %.4f, "
                           "needs %.3f)", v.conditioning, st.min_conditioning);
        else if (v.violation > st.max_violation)
            f.reason = fmt("%.0f%% of nearby points lie inside the fiducial's solid (at most %.0f%%)",
                           100 * v.violation, 100 * st.max_violation);
        else if (v.coverage < st.min_coverage)
            f.reason = fmt("only %.0f%% of the fiducial's visible surface observed (needs %.0f%%)",
                           100 * v.coverage, 100 * st.min_coverage);
        else if (v.rmse > st.max_rmse * vs.inlier_distance)
            f.reason = fmt("residual %.4g is above %.4g", v.rmse, st.max_rmse * vs.inlier_distance);
        f.accepted = f.reason.empty();
        tried.push_back(std::move(t));
    }
    best.candidates = n;
    if (tried.empty()) {
        best.reason = "no candidate pose had enough scan points around it";
        return best;
    }
    // The best accepted pose by support; without one, the most convincing rejected one explains why.
    auto support = [](const Tried& t) { return t.fit.inliers * t.fit.score; };
    const Tried* top = nullptr;
    for (const auto& t : tried)
        if (t.fit.accepted && (!top || support(t) > support(*top))) top = &t;
    if (!top) {
        for (const auto& t : tried)
            if (!top || support(t) > support(*top)) top = &t;
        best = top->fit;
        best.candidates = n;
        best.accepted = false;
        return best;
    }
    best = top->fit;
    best.candidates = n;
    for (const auto& t : tried) {
        if (&t == top || !t.fit.accepted) continue;
        const PoseError e = pose_error(t.fit.T_scan_fiducial, top->fit.T_scan_fiducial);
        if ((e.translation > 2.0 * ms || e.rotation_deg > 2.0) &&
            t.fit.inliers * t.fit.score >= st.ambiguity * support(*top)) {
            best.accepted = false;
            best.reason = fmt("ambiguous: two poses %.3g apart fit about equally well (%.0f%% of the support)",
                              e.translation, 100.0 * support(t) / support(*top));
            break;
        }
    }
    return best;
}

}  // namespace partloc
