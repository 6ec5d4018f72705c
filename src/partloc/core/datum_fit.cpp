#include "partloc/core/datum_fit.hpp"

#include <tbb/blocked_range.h>
#include <tbb/parallel_reduce.h>

#include <Eigen/Eigenvalues>
#include <cmath>
#include <cstdio>

#include "partloc/core/icp.hpp"

namespace partloc {

namespace {

/// Gauss-Newton sums of one datum, in scaled twist coordinates [L w, v] about the centre c.
struct System {
    Matrix6d H = Matrix6d::Zero();   ///< sum w J J^T
    Matrix6d H2 = Matrix6d::Zero();  ///< sum w^2 J J^T: for unit noise, the covariance of g
    Vector6d g = Vector6d::Zero();
    double r2 = 0.0;
    std::size_t n = 0;
};

using Systems = std::vector<System>;

Systems add(const Systems& a, const Systems& b) {
    Systems s = a;
    for (std::size_t k = 0; k < s.size(); ++k) {
        s[k].H += b[k].H;
        s[k].H2 += b[k].H2;
        s[k].g += b[k].g;
        s[k].r2 += b[k].r2;
        s[k].n += b[k].n;
    }
    return s;
}

/// Where a point (already in the nominal frame) lies: the datum whose surface is within max_distance, its
/// nearest tangent plane's residual and normal. -1 when on none, or on two (at a shared edge).
struct Match {
    int datum = -1;
    double r = 0.0;
    Eigen::Vector3d n = Eigen::Vector3d::Zero();
};

Match match(const Eigen::Vector3d& q, const std::vector<DatumSurface>& datums, double max_distance) {
    Match m;
    int idx[4];
    double d2[4];
    for (std::size_t k = 0; k < datums.size(); ++k) {
        const Surface& s = datums[k].surface;
        const int found = s.nearest(q, 4, max_distance, idx, d2);
        if (found < 1) continue;
        if (m.datum >= 0) return {};  // near two datums: a point at their edge belongs to neither for sure
        // Of the nearest samples, the one whose tangent plane is nearest (as in icp.cpp).
        int best = idx[0];
        double r = (q - s.points[best]).dot(s.normals[best]);
        for (int j = 1; j < found; ++j) {
            const double rj = (q - s.points[idx[j]]).dot(s.normals[idx[j]]);
            if (std::abs(rj) < std::abs(r)) {
                r = rj;
                best = idx[j];
            }
        }
        m = {static_cast<int>(k), r, s.normals[best]};
    }
    return m;
}

struct Frame {
    Eigen::Vector3d c = Eigen::Vector3d::Zero();  ///< centre of the scaled twist
    double L = 1.0;                               ///< rotations are scaled by this length
};

Systems accumulate(const std::vector<Eigen::Vector3d>& pts, const std::vector<DatumSurface>& datums,
                   const Eigen::Isometry3d& T, double max_distance, bool weighted, const Frame& f) {
    return tbb::parallel_deterministic_reduce(  // the same sums for any number of threads (icp.cpp)
        tbb::blocked_range<std::size_t>(0, pts.size(), 512), Systems(datums.size()),
        [&](const tbb::blocked_range<std::size_t>& range, Systems acc) {
            for (std::size_t i = range.begin(); i != range.end(); ++i) {
                const Eigen::Vector3d q = T * pts[i];
                const Match m = match(q, datums, max_distance);
                if (m.datum < 0) continue;
                const double w = weighted ? tukey_weight(m.r, max_distance) : 1.0;
                Vector6d J;
                J << (q - f.c).cross(m.n) / f.L, m.n;
                System& s = acc[static_cast<std::size_t>(m.datum)];
                s.H.noalias() += w * J * J.transpose();
                s.H2.noalias() += w * w * J * J.transpose();
                s.g.noalias() -= w * m.r * J;
                s.r2 += m.r * m.r;
                ++s.n;
            }
            return acc;
        },
        add);
}

/// Each datum's own degrees of freedom: the `dof` directions, of those the datums before it left, that its
/// information constrains best (largest eigenvalues of its information restricted to them).
struct Hierarchy {
    std::vector<Eigen::MatrixXd> U;    ///< 6 x dof_k, orthonormal in the scaled coordinates
    std::vector<double> conditioning;  ///< smallest chosen eigenvalue per point
};

Hierarchy hierarchy(const Systems& sys, const std::array<int, 3>& dof) {
    Hierarchy h;
    Eigen::MatrixXd F = Eigen::MatrixXd::Identity(6, 6);  // the directions still free
    for (std::size_t k = 0; k < sys.size(); ++k) {
        const Eigen::MatrixXd P = F.transpose() * sys[k].H * F;
        const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> es(P);
        const int m = static_cast<int>(F.cols());
        const int d = std::min(dof[k], m);
        h.U.push_back(F * es.eigenvectors().rightCols(d));
        h.conditioning.push_back(
            sys[k].n ? std::max(0.0, es.eigenvalues()(m - d)) / static_cast<double>(sys[k].n) : 0.0);
        F = Eigen::MatrixXd(F * es.eigenvectors().leftCols(m - d));
    }
    return h;
}

/// One step, datum by datum: datum k solves for its own directions given the steps of those before it.
Vector6d solve(const Systems& sys, const std::vector<Vector6d>& g, const Hierarchy& h) {
    Vector6d delta = Vector6d::Zero();
    for (std::size_t k = 0; k < sys.size(); ++k) {
        const Eigen::MatrixXd& U = h.U[k];
        const Eigen::MatrixXd A = U.transpose() * sys[k].H * U;
        const Eigen::VectorXd rhs = U.transpose() * (g[k] - sys[k].H * delta);
        delta += U * A.ldlt().solve(rhs);
    }
    return delta;
}

Frame frame_of(const std::vector<DatumSurface>& datums) {
    Eigen::AlignedBox3d box;
    for (const auto& d : datums)
        for (const auto& p : d.surface.points) box.extend(p);
    Frame f;
    f.c = box.center();
    f.L = std::max(0.5 * box.diagonal().norm(), 1e-12);
    return f;
}

double last_distance(const std::vector<DatumSurface>& datums, const DatumFitSettings& st) {
    if (st.max_distance > 0) return st.max_distance;
    double sample = 0.0;
    for (const auto& d : datums) sample = std::max(sample, d.surface.spacing);
    return std::sqrt(9.0 * st.noise * st.noise + 0.25 * sample * sample);
}

/// Why the datums do not fix their degrees of freedom; empty when they do.
std::string unfixed(const Hierarchy& h, const std::vector<DatumSurface>& datums, const DatumFitSettings& st) {
    for (std::size_t k = 0; k < datums.size(); ++k)
        if (!(h.conditioning[k] >= st.min_conditioning)) {
            char buf[300];
            std::snprintf(buf, sizeof buf,
                          "datum %s does not fix the %d degree(s) of freedom left to it (conditioning %.2g, "
                          "needs %.2g)",
                          datums[k].name.c_str(), st.dof[k], h.conditioning[k], st.min_conditioning);
            return buf;
        }
    return "";
}

std::vector<DatumResidual> residuals(const Systems& sys, const std::vector<DatumSurface>& datums) {
    std::vector<DatumResidual> out;
    for (std::size_t k = 0; k < datums.size(); ++k)
        out.push_back({datums[k].name, sys[k].n, sys[k].n ? std::sqrt(sys[k].r2 / sys[k].n) : 0.0, 0, 0.0});
    return out;
}

}  // namespace

std::vector<DatumResidual> evaluate_datums(const std::vector<Eigen::Vector3d>& merged,
                                           const std::vector<DatumSurface>& datums,
                                           const Eigen::Isometry3d& T_located_nominal,
                                           const DatumFitSettings& st) {
    const Frame f = frame_of(datums);
    return residuals(
        accumulate(merged, datums, T_located_nominal.inverse(), last_distance(datums, st), false, f), datums);
}

DatumFit fit_datums(const std::vector<Eigen::Vector3d>& merged, const std::vector<DatumSurface>& datums,
                    const Eigen::Isometry3d& T_correction_start, const DatumFitSettings& st) {
    DatumFit fit;
    fit.T_located_nominal = T_correction_start;
    if (datums.size() != 3) {
        fit.reason = "the datum fit needs three datums (primary, secondary, tertiary), found " +
                     std::to_string(datums.size());
        return fit;
    }
    for (const auto& d : datums)
        if (d.surface.points.empty()) {
            fit.reason = "datum " + d.name + " has no surface";
            return fit;
        }
    const Frame f = frame_of(datums);
    const double fine = last_distance(datums, st);
    const std::vector<double> stages = {2.0 * fine, fine};

    // Only points near a datum at the start can take part; the rest need not be searched every step.
    Eigen::Isometry3d T = T_correction_start.inverse();  // merged points -> nominal
    std::vector<Eigen::Vector3d> near;
    {
        for (const auto& p : merged) {
            const Eigen::Vector3d q = T * p;
            for (const auto& d : datums)
                if (d.surface.nearest(q, nullptr, 1.5 * stages.front()) >= 0) {
                    near.push_back(p);
                    break;
                }
        }
    }

    Hierarchy h;
    fit.converged = true;
    for (double max_distance : stages) {
        bool converged = false;
        for (int it = 0; it < st.max_iterations; ++it) {
            const Systems sys = accumulate(near, datums, T, max_distance, true, f);
            ++fit.iterations;
            for (std::size_t k = 0; k < datums.size(); ++k)
                if (sys[k].n < st.min_points) {
                    fit.reason = "datum " + datums[k].name + ": only " + std::to_string(sys[k].n) +
                                 " points lie on it (needs " + std::to_string(st.min_points) + ")";
                    return fit;
                }
            h = hierarchy(sys, st.dof);
            if (const std::string why = unfixed(h, datums, st); !why.empty()) {
                fit.reason = why;
                return fit;
            }
            std::vector<Vector6d> g;
            for (const auto& s : sys) g.push_back(s.g);
            const Vector6d delta = solve(sys, g, h);
            T = motion_about(delta, f.c, f.L) * T;
            if (delta.head<3>().norm() / f.L + delta.tail<3>().norm() / f.L < st.min_step) {
                converged = true;
                break;
            }
        }
        fit.converged = fit.converged && converged;
    }

    // The result at the last stage's distance: residuals (unweighted), and the covariance of the estimate.
    const Systems sys = accumulate(near, datums, T, fine, true, f);
    fit.T_located_nominal = T.inverse();
    fit.datums = residuals(sys, datums);
    h = hierarchy(sys, st.dof);
    double r2 = 0.0;
    for (std::size_t k = 0; k < datums.size(); ++k) {
        fit.datums[k].dof = st.dof[k];
        fit.datums[k].conditioning = h.conditioning[k];
        fit.inliers += sys[k].n;
        r2 += sys[k].r2;
    }
    fit.rmse = fit.inliers ? std::sqrt(r2 / fit.inliers) : 0.0;

    // The step is linear in the datums' gradients: delta = sum_k M_k g_k, and for unit noise
    // Cov(g_k) = sum w^2 J J^T (Tukey weights w), so Cov(delta) = sum_k M_k H2_k M_k^T (the datums' points
    // are disjoint, hence independent): the sandwich covariance of an M-estimator.
    Matrix6d cov_scaled = Matrix6d::Zero();
    for (std::size_t k = 0; k < datums.size(); ++k) {
        Matrix6d M;
        for (int i = 0; i < 6; ++i) {
            std::vector<Vector6d> g(datums.size(), Vector6d::Zero());
            g[k](i) = 1.0;
            M.col(i) = solve(sys, g, h);
        }
        cov_scaled += M * sys[k].H2 * M.transpose();
    }
    // [L w, v] about c  ->  [w, v0] about the origin: v0 = v - w x c = v + c x w.
    Matrix6d A = Matrix6d::Zero();
    Eigen::Matrix3d C;
    C << 0, -f.c.z(), f.c.y(), f.c.z(), 0, -f.c.x(), -f.c.y(), f.c.x(), 0;
    A.topLeftCorner<3, 3>() = Eigen::Matrix3d::Identity() / f.L;
    A.bottomLeftCorner<3, 3>() = C / f.L;
    A.bottomRightCorner<3, 3>() = Eigen::Matrix3d::Identity();
    fit.covariance = A * cov_scaled * A.transpose();
    fit.information = fit.covariance.fullPivLu().inverse();

    fit.reason = unfixed(h, datums, st);
    fit.valid = fit.reason.empty();
    return fit;
}

}  // namespace partloc
