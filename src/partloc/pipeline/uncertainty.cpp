#include "partloc/pipeline/uncertainty.hpp"

#include <tbb/parallel_for.h>

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <tuple>
#include <utility>

#include "partloc/core/workpiece_fit.hpp"

namespace partloc {

namespace {

struct Pose6 {
    Eigen::Vector3d origin, euler;
};

Pose6 pose6(const Eigen::Isometry3d& T) { return {T.translation(), euler_xyz_deg(T.linear())}; }

Eigen::Vector3d euler_difference(const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
    return Eigen::Vector3d(wrap_deg(a.x() - b.x()), wrap_deg(a.y() - b.y()), wrap_deg(a.z() - b.z()));
}

/// The adjoint of a rigid motion on twists [w, v] about the origin: the same motion of space, seen after T.
Matrix6d adjoint(const Eigen::Isometry3d& T) {
    const Eigen::Matrix3d R = T.linear();
    Matrix6d A = Matrix6d::Zero();
    A.topLeftCorner<3, 3>() = R;
    A.bottomLeftCorner<3, 3>() = skew(T.translation()) * R;
    A.bottomRightCorner<3, 3>() = R;
    return A;
}

/// 1-sigma of the shift at point p, per axis, and of the turn in degrees, from a twist covariance.
std::pair<Eigen::Vector3d, Eigen::Vector3d> sigmas_at(const Eigen::Vector3d& p, const Matrix6d& cov) {
    return {shift_covariance_at(cov, p).diagonal().cwiseMax(0.0).cwiseSqrt(),
            cov.topLeftCorner<3, 3>().diagonal().cwiseMax(0.0).cwiseSqrt() * 180.0 / M_PI};
}

/// The part fitted again without each scan, on the points of the others that the fit took: each refit's
/// pose, and the scan it left out.
struct LeaveOneOut {
    std::vector<Pose6> poses;
    std::vector<int> left_out;
};

LeaveOneOut leave_one_out(const UncertaintyInputs& in, const WorkpieceResult& w) {
    const int n = static_cast<int>(in.scan_points.size());
    std::vector<std::vector<Eigen::Vector3d>> pts(n), nrm(n);
    for (int i = 0; i < n; ++i) {
        const auto& c = *in.scan_points[i];
        const std::size_t stride = scan_stride(c.points_.size(), in.scan_points_most);
        for (std::size_t k = 0; k < c.points_.size(); k += stride) {
            pts[i].push_back(c.points_[k]);
            if (c.HasNormals()) nrm[i].push_back(c.normals_[k]);
        }
    }
    LeaveOneOut out;
    for (int i = 0; i < n; ++i) {
        std::vector<Eigen::Vector3d> p, q;
        bool normals = true;
        for (int j = 0; j < n; ++j) {
            if (j == i) continue;
            p.insert(p.end(), pts[j].begin(), pts[j].end());
            q.insert(q.end(), nrm[j].begin(), nrm[j].end());
            normals = normals && nrm[j].size() == pts[j].size();
        }
        if (in.refit) {
            const auto T = in.refit(p, normals ? &q : nullptr);
            if (T) {
                out.poses.push_back(pose6(*T * w.T_machine_workpiece_nominal));
                out.left_out.push_back(i);
            }
            continue;
        }
        const IcpResult r = fit_last_stage(p, *in.reference, in.T_located_nominal.inverse(), in.fit_distance,
                                           normals ? &q : nullptr);
        if (r.inliers < 100) continue;
        out.poses.push_back(pose6(r.T_target_source.inverse() * w.T_machine_workpiece_nominal));
        out.left_out.push_back(i);
    }
    return out;
}

/// The jackknife's sigmas of the origin and the angles from the refits' scatter about the full fit.
void jackknife_sigmas(const std::vector<Pose6>& loo, const Pose6& full, Uncertainty& u) {
    const int m = static_cast<int>(loo.size());
    Eigen::Vector3d mo = Eigen::Vector3d::Zero(), me = Eigen::Vector3d::Zero();
    for (const auto& l : loo) {
        mo += l.origin;
        me += euler_difference(l.euler, full.euler);
    }
    mo /= m;
    me /= m;
    Eigen::Vector3d vo = Eigen::Vector3d::Zero(), ve = Eigen::Vector3d::Zero();
    for (const auto& l : loo) {
        vo += (l.origin - mo).cwiseAbs2();
        ve += (euler_difference(l.euler, full.euler) - me).cwiseAbs2();
    }
    const double jk = (m - 1.0) / m;
    u.origin_scans = (jk * vo).cwiseSqrt();
    u.euler_scans = (jk * ve).cwiseSqrt();
}

/// How the fiducials' probing errors reach the part. An error in fiducial f's probed pose (a twist d_f,
/// machine frame where it was probed) moves each scan it fixes by H_s^-1 H_sf d_f (H_sf: f's share of the
/// scan fit's JtJ, H_s their sum), and the part by sum_s W_s of those (W_s = H^-1 H_s over the part fit's
/// JtJ per scan). The errors of the fiducials are independent, and each one's is the same in every scan it
/// fixes, so it does not average out over them.
struct ProbingPaths {
    std::vector<Matrix6d> scan_part_jtj;  ///< each scan's share of the part fit's JtJ
    Matrix6d part_jtj = Matrix6d::Zero();
    /// moves[f]: (scan, that scan's twist per unit of f's twist at axes 0), scans ascending.
    std::vector<std::vector<std::pair<int, Matrix6d>>> moves;

    /// Each scan's weight in the part's fit on every scan but `without` (-1: all of them).
    std::vector<Matrix6d> weights(int without) const {
        const int n = static_cast<int>(scan_part_jtj.size());
        Matrix6d H = part_jtj;
        if (without >= 0) H -= scan_part_jtj[without];
        const Eigen::LDLT<Matrix6d> solver(H);
        const int with = n - (without >= 0 ? 1 : 0);
        std::vector<Matrix6d> W(n, Matrix6d::Zero());
        for (int i = 0; i < n; ++i)
            if (i != without)
                W[i] = H.isZero() ? Matrix6d(Matrix6d::Identity() / static_cast<double>(with))
                                  : Matrix6d(solver.solve(scan_part_jtj[i]));
        return W;
    }
    /// The part's twist per unit of f's twist, fitted with the weights W (a scan left out weighs nothing).
    Matrix6d part_per_fiducial(std::size_t f, const std::vector<Matrix6d>& W) const {
        Matrix6d M = Matrix6d::Zero();
        for (const auto& [i, K] : moves[f]) M += W[i] * K;
        return M;
    }
};

ProbingPaths probing_paths(const Job& job, const UncertaintyInputs& in) {
    const int n = static_cast<int>(in.scan_points.size());
    ProbingPaths paths;
    paths.scan_part_jtj.assign(n, Matrix6d::Zero());
    const Eigen::Isometry3d T_nominal_located = in.T_located_nominal.inverse();
    // The scans side by side, each one's sum in its points' order (the same bits for any number of threads).
    tbb::parallel_for(0, n, [&](int i) {
        const auto& c = *in.scan_points[i];
        const std::size_t stride = scan_stride(c.points_.size(), in.scan_points_most);
        for (std::size_t k = 0; k < c.points_.size(); k += stride) {
            double d2 = 0.0;
            const int j = in.reference->nearest(T_nominal_located * c.points_[k], &d2, in.fit_distance);
            if (j < 0) continue;
            const Eigen::Vector3d nm = in.T_located_nominal.linear() * in.reference->normals[j];
            Vector6d J;
            J << c.points_[k].cross(nm), nm;
            paths.scan_part_jtj[i] += static_cast<double>(stride) * J * J.transpose();
        }
    });
    for (int i = 0; i < n; ++i) paths.part_jtj += paths.scan_part_jtj[i];
    paths.moves.resize(job.fiducials.size());
    for (int i = 0; i < n; ++i) {
        const auto& ks = in.scan_fiducials[i];
        const bool have_jtj =
            i < static_cast<int>(in.scan_fiducial_jtj.size()) && in.scan_fiducial_jtj[i].size() == ks.size();
        const bool have_motion = i < static_cast<int>(in.scan_fiducial_motion.size()) &&
                                 in.scan_fiducial_motion[i].size() == ks.size();
        const Eigen::Isometry3d Q = i < static_cast<int>(in.scan_to_axes0.size())
                                        ? in.scan_to_axes0[i]
                                        : Eigen::Isometry3d::Identity();
        Matrix6d Hs = Matrix6d::Zero();
        if (have_jtj)
            for (const auto& Hf : in.scan_fiducial_jtj[i]) Hs += Hf;
        const Eigen::LDLT<Matrix6d> scan_solver(Hs);  // once per scan, for each of its fiducials
        for (std::size_t slot = 0; slot < ks.size(); ++slot) {
            const Matrix6d share = have_jtj ? Matrix6d(scan_solver.solve(in.scan_fiducial_jtj[i][slot]))
                                            : Matrix6d(Matrix6d::Identity() / static_cast<double>(ks.size()));
            const Eigen::Isometry3d G =
                have_motion ? in.scan_fiducial_motion[i][slot] : Eigen::Isometry3d::Identity();
            if (ks[slot] < paths.moves.size())
                paths.moves[ks[slot]].emplace_back(i, adjoint(Q) * share * adjoint(G));
        }
    }
    return paths;
}

/// The probing's sigmas at the part, and how much of it the jackknife's refits (which left out the scans
/// `left_out`) already scatter by (reported, not subtracted: the double count pays for the heavy tails of
/// three to six refits; docs/history.md).
void probing_sigmas(const Job& job, const ProbingPaths& paths, const std::vector<int>& left_out,
                    const Pose6& full, Uncertainty& u) {
    const int m = static_cast<int>(left_out.size());
    const std::vector<Matrix6d> W_full = paths.weights(-1);
    std::vector<std::vector<Matrix6d>> W_loo;
    for (const int i : left_out) W_loo.push_back(paths.weights(i));
    Matrix6d cov_probing = Matrix6d::Zero(), cov_probing_in_scans = Matrix6d::Zero();
    for (std::size_t f = 0; f < job.fiducials.size(); ++f) {
        const auto& fid = job.fiducials[f];
        const double sigma = fid.pose_sigma;  // the loader sets the default, 0.005 mm; 0 means exact
        if (sigma <= 0) continue;
        if (paths.moves[f].empty()) continue;  // in no scan of the fit
        // f's probing error: sigma per axis in translation and sigma over half the block's size in each
        // turn, both about the block's centre; as a twist about the machine's origin.
        const auto box = bounding_box(fid.model);
        const double half = std::max(0.5 * box.diagonal().norm(), 1e-9);
        Vector6d var;
        var << Eigen::Vector3d::Constant(std::pow(sigma / half, 2)), Eigen::Vector3d::Constant(sigma * sigma);
        Eigen::Isometry3d about = Eigen::Isometry3d::Identity();
        about.translation() = fid.T_machine_fiducial * box.center();
        const Matrix6d A = adjoint(about);
        const Matrix6d cov_f = A * var.asDiagonal() * A.transpose();
        const Matrix6d M = paths.part_per_fiducial(f, W_full);
        cov_probing += M * cov_f * M.transpose();
        std::vector<Matrix6d> Ms;
        Matrix6d mean = Matrix6d::Zero();
        for (const auto& W : W_loo) {
            Ms.push_back(paths.part_per_fiducial(f, W));
            mean += Ms.back();
        }
        mean /= static_cast<double>(m);
        for (const auto& Mi : Ms) cov_probing_in_scans += (Mi - mean) * cov_f * (Mi - mean).transpose();
    }
    cov_probing_in_scans *= (m - 1.0) / m;
    std::tie(u.origin_probing, u.euler_probing) = sigmas_at(full.origin, cov_probing);
    std::tie(u.origin_probing_in_scans, u.euler_probing_in_scans) =
        sigmas_at(full.origin, cov_probing_in_scans);
}

}  // namespace

void estimate_uncertainty(const Job& job, const UncertaintyInputs& in, WorkpieceResult& w) {
    Uncertainty& u = w.uncertainty;
    u = Uncertainty{};
    const int n = static_cast<int>(in.scan_points.size());
    u.scans = n;
    // The jackknife needs redundancy: with fewer than three scans there is no honest estimate of how much
    // one scan moves the answer.
    if (!w.valid || n < 3 || !in.reference) return;
    const Pose6 full = pose6(w.T_machine_workpiece);

    // The scans: the scatter of the part fitted again without each one.
    const LeaveOneOut loo = leave_one_out(in, w);
    if (loo.poses.size() < 3) return;
    jackknife_sigmas(loo.poses, full, u);

    // The probing: common to every scan a fiducial fixes.
    probing_sigmas(job, probing_paths(job, in), loo.left_out, full, u);

    // The noise: the fit's information matrix.
    const Matrix6d& info = in.information;
    Eigen::SelfAdjointEigenSolver<Matrix6d> es(info);
    if (es.eigenvalues()(0) > 0) {
        const Matrix6d cov =
            es.eigenvectors() * es.eigenvalues().cwiseInverse().asDiagonal() * es.eigenvectors().transpose();
        std::tie(u.origin_noise, u.euler_noise) = sigmas_at(full.origin, cov);
    }

    // The jackknife, never less than the noise's own sigma (the scatter of three to five refits can come
    // out far below it), and the probing, which the jackknife sees only where scans differ in their
    // fiducials, in quadrature, times 1.96. How this rule was chosen and how often it held the truth:
    // BENCHMARK.md (uncertainty) and docs/history.md.
    for (int a = 0; a < 3; ++a) {
        u.origin(a) = 1.96 * std::hypot(std::max(u.origin_scans(a), u.origin_noise(a)), u.origin_probing(a));
        u.euler_deg(a) = 1.96 * std::hypot(std::max(u.euler_scans(a), u.euler_noise(a)), u.euler_probing(a));
    }
    u.scans = static_cast<int>(loo.poses.size());
    u.available = true;
}

}  // namespace partloc
