#include "partloc/core/verify.hpp"

#include <Eigen/Eigenvalues>
#include <cmath>
#include <limits>
#include <unordered_map>

namespace partloc {

namespace {

// Gnomonic projection about the ray from the eye to the model's centre: small, singularity-free bins.
struct RayBins {
    Eigen::Vector3d eye, a, e1, e2;
    double beta;  // bin width as tan(angle)
    bool bin(const Eigen::Vector3d& p, std::int64_t* key, double* range) const {
        const Eigen::Vector3d d = p - eye;
        const double z = d.dot(a);
        if (z <= 0) return false;
        const auto ix = static_cast<std::int64_t>(std::floor(d.dot(e1) / z / beta));
        const auto iy = static_cast<std::int64_t>(std::floor(d.dot(e2) / z / beta));
        *key = (ix + (1 << 30)) * (std::int64_t(1) << 31) + (iy + (1 << 30));
        *range = d.norm();
        return true;
    }
};

struct BinState {
    double model_range = std::numeric_limits<double>::infinity();
    std::size_t sample = 0;  // the model sample the scanner would see in this bin
    bool facing = false;
    bool on = false, behind = false, crowded = false, front = false;
};

/// A point's row of the fit's Jacobian about the model's centre, rotations scaled by half its diameter:
/// [(p - c) x n / (d/2), n], in which the conditioning and the weakest direction are measured.
Vector6d centred_row(const Eigen::Vector3d& p, const Eigen::Vector3d& n, const Surface& model) {
    Vector6d J;
    J << (p - model.center).cross(n) / std::max(model.diameter / 2.0, 1e-12), n;
    return J;
}

/// The points on the model's surface: their residuals, and how well they fix the pose (inliers, rmse,
/// JtJ, conditioning, spread, overflow).
void surface_support(const std::vector<Eigen::Vector3d>& pts, const Surface& model,
                     const Eigen::Vector3d& eye, const VerifySettings& s, Verification& v) {
    double r2 = 0.0;
    Matrix6d Jn = Matrix6d::Zero(), edge_on = Matrix6d::Zero();
    Eigen::Matrix3d N = Eigen::Matrix3d::Zero();
    const double reach = std::max(4.0 * model.spacing, 0.05 * model.diameter);
    int knn_idx[6];
    double knn_d2[6];
    // A point is on the model when it lies on the tangent plane of one of its nearest samples, within that
    // sample's share of the surface (a Poisson-disk sample covers a disk of about its spacing). Several
    // samples are looked at because at an edge the nearest may lie on the other face.
    const double cover = 1.5 * model.spacing;
    for (const auto& p : pts) {
        // The nearest six within the reach: beyond it no sample can hold the point (cover and inlier distance
        // are far smaller) or tell of a facing plane continued.
        const int found = model.nearest(p, 6, reach, knn_idx, knn_d2);
        if (found < 1) continue;
        int on = -1;
        bool facing_plane = false;
        for (int j = 0; j < found; ++j) {
            const int k = knn_idx[j];
            const Eigen::Vector3d& n = model.normals[k];
            const Eigen::Vector3d d = p - model.points[k];
            const double along = d.dot(n);
            if (std::abs(along) > s.inlier_distance) continue;
            if ((d - along * n).norm() <= cover) {
                on = k;
                break;
            }
            facing_plane = facing_plane || (eye - model.points[k]).dot(n) > 0;
        }
        if (on < 0) {
            // A face that the scanner sees, continued past the model's edge: the model ends where the
            // surface does not (a model sunk flush into a larger body, or a smaller look-alike).
            if (facing_plane) ++v.overflow;
            continue;
        }
        const Eigen::Vector3d& n = model.normals[on];
        const double along = (p - model.points[on]).dot(n);
        ++v.inliers;
        r2 += along * along;
        Vector6d J;
        J << p.cross(n), n;
        v.JtJ.noalias() += J * J.transpose();
        // Summed over the few points seen edge-on and taken from the whole at the end: the same sums at a
        // fraction of the work (seed 106's run took 5 % longer when the facing ones were summed).
        const Eigen::Vector3d to_eye = eye - p;
        const double along_n = to_eye.dot(n);
        if (along_n * along_n < s.facing_cos * s.facing_cos * to_eye.squaredNorm())
            edge_on.noalias() += J * J.transpose();
        const Vector6d Jc = centred_row(p, n, model);
        Jn.noalias() += Jc * Jc.transpose();
        N.noalias() += n * n.transpose();
    }
    v.JtJ_facing = v.JtJ - edge_on;
    if (v.inliers) {
        v.rmse = std::sqrt(r2 / v.inliers);
        Eigen::SelfAdjointEigenSolver<Matrix6d> es(Jn / static_cast<double>(v.inliers));
        v.conditioning = std::max(0.0, es.eigenvalues()(0));
        v.weakest = es.eigenvectors().col(0);
        Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> en(N / static_cast<double>(v.inliers));
        v.spread = std::max(0.0, en.eigenvalues()(0));
    }
}

/// The model's visible surface along the scanner's rays (a z-buffer of its samples) against the returns:
/// observed, seen through, crowded, occluded and missing bins. False when the eye is at the model's centre.
bool ray_bins(const std::vector<Eigen::Vector3d>& pts, const Surface& model, const Eigen::Vector3d& eye,
              const VerifySettings& s, Verification& v) {
    RayBins rb;
    rb.eye = eye;
    const Eigen::Vector3d to_model = model.center - rb.eye;
    const double dist = to_model.norm();
    if (dist < 1e-12) return false;
    rb.a = to_model / dist;
    rb.e1 = rb.a.unitOrthogonal();
    rb.e2 = rb.a.cross(rb.e1);
    rb.beta = s.bin_size / dist;
    std::unordered_map<std::int64_t, BinState> bins;
    bins.reserve(model.points.size());
    std::int64_t key;
    double range;
    for (std::size_t i = 0; i < model.points.size(); ++i) {
        if (!rb.bin(model.points[i], &key, &range)) continue;
        BinState& b = bins[key];
        if (range < b.model_range) {
            b.model_range = range;
            b.sample = i;
            const Eigen::Vector3d ray = (model.points[i] - rb.eye) / range;
            b.facing = -ray.dot(model.normals[i]) > s.facing_cos;
        }
    }
    // On or off the surface by the distance to the visible sample's tangent plane (a bin spans a range of
    // depths on an inclined face); in front or behind by the range along the ray.
    const double tol = s.inlier_distance;
    // Something that hides the model must stand clear of it: a surface just in front of the model's
    // surface is the model's own material in another place, i.e. the pose is wrong (a block of the same
    // heights turned, say).
    const double near = std::max(4.0 * tol, s.near_fraction * model.diameter);
    for (const auto& p : pts) {
        if (!rb.bin(p, &key, &range)) continue;
        const auto it = bins.find(key);
        if (it == bins.end()) continue;
        BinState& b = it->second;
        const double delta = range - b.model_range;
        const double off = std::abs((p - model.points[b.sample]).dot(model.normals[b.sample]));
        if (off <= tol && std::abs(delta) <= tol + s.bin_size)
            b.on = true;
        else if (delta > 0)
            b.behind = true;
        else if (delta < -near)
            b.front = true;
        else
            b.crowded = true;
    }
    // Only a bin inside the model's outline can contradict it: at the outline a bin straddles the model's
    // edge and the background behind it.
    auto interior = [&](std::int64_t k, const BinState& b) {
        const std::int64_t step = std::int64_t(1) << 31;
        for (std::int64_t nk : {k - 1, k + 1, k - step, k + step}) {
            const auto it = bins.find(nk);
            if (it == bins.end() || std::abs(it->second.model_range - b.model_range) > 3.0 * s.bin_size)
                return false;
        }
        return true;
    };
    // A bin's sample holds the weakest direction when its row gives it at least holding_share of the most
    // any unit normal could (none without inliers, where there is no weakest direction).
    const double most = v.weakest.head<3>().norm() + v.weakest.tail<3>().norm();
    const auto holds = [&](const BinState& b) {
        return most > 0.0 &&
               std::abs(centred_row(model.points[b.sample], model.normals[b.sample], model).dot(v.weakest)) >=
                   s.holding_share * most;
    };
    for (const auto& [k, b] : bins) {
        if (!b.facing) continue;
        if (b.on) {
            ++v.observed;
            v.weakest_observed += holds(b);
        } else if (!interior(k, b)) {
            ++v.occluded;
        } else if (b.crowded) {
            ++v.crowded;
            v.weakest_against += holds(b);
        } else if (b.behind && !b.front) {
            ++v.seen_through;
            v.weakest_against += holds(b);
        } else if (b.front) {
            ++v.occluded;
        } else {
            ++v.missing;
        }
    }
    return true;
}

}  // namespace

Verification verify_pose(const std::vector<Eigen::Vector3d>& scan_points, const Surface& model,
                         const Eigen::Isometry3d& T_model_scan, const Eigen::Vector3d& viewpoint_scan,
                         const VerifySettings& s) {
    Verification v;
    if (model.points.empty()) return v;

    std::vector<Eigen::Vector3d> pts;
    pts.reserve(scan_points.size());
    for (const auto& p : scan_points) pts.push_back(T_model_scan * p);
    const Eigen::Vector3d eye = T_model_scan * viewpoint_scan;
    surface_support(pts, model, eye, s, v);
    if (!ray_bins(pts, model, eye, s, v)) return v;
    const std::size_t judged = v.observed + v.seen_through + v.crowded + v.missing;
    v.coverage = judged ? static_cast<double>(v.observed) / judged : 0.0;
    v.violation = static_cast<double>(v.seen_through + v.crowded) /
                  std::max<std::size_t>(1, v.observed + v.seen_through + v.crowded);
    return v;
}

}  // namespace partloc
