#include "partloc/core/geometry.hpp"

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace partloc {

namespace {
constexpr double kDeg = M_PI / 180.0;
}

Eigen::Matrix3d rotation_from_euler_xyz_deg(const Eigen::Vector3d& e) {
    return (Eigen::AngleAxisd(e.z() * kDeg, Eigen::Vector3d::UnitZ()) *
            Eigen::AngleAxisd(e.y() * kDeg, Eigen::Vector3d::UnitY()) *
            Eigen::AngleAxisd(e.x() * kDeg, Eigen::Vector3d::UnitX()))
        .toRotationMatrix();
}

Eigen::Vector3d euler_xyz_deg(const Eigen::Matrix3d& R) {
    // R = Rz(c) Ry(b) Rx(a): R(2,0) = -sin b, R(2,1) = cos b sin a, R(2,2) = cos b cos a,
    // R(1,0) = sin c cos b, R(0,0) = cos c cos b.
    const double sb = std::clamp(-R(2, 0), -1.0, 1.0);
    const double b = std::asin(sb);
    double a, c;
    if (std::abs(sb) < 1.0 - 1e-12) {
        a = std::atan2(R(2, 1), R(2, 2));
        c = std::atan2(R(1, 0), R(0, 0));
    } else {  // gimbal lock: only a - c (or a + c) is defined; put it all in a
        c = 0.0;
        a = std::atan2(-R(1, 2), R(1, 1));
    }
    return Eigen::Vector3d(a, b, c) / kDeg;
}

Eigen::Isometry3d pose_from_origin_euler(const Eigen::Vector3d& origin, const Eigen::Vector3d& euler_deg) {
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
    T.linear() = rotation_from_euler_xyz_deg(euler_deg);
    T.translation() = origin;
    return T;
}

Eigen::Isometry3d checked_isometry(const Eigen::Matrix4d& M, const std::string& what, double tol) {
    if (!M.allFinite()) throw std::invalid_argument(what + ": matrix has non-finite entries");
    if (M.row(3).transpose().cwiseAbs().maxCoeff() > 0 &&
        (M.row(3) - Eigen::RowVector4d(0, 0, 0, 1)).cwiseAbs().maxCoeff() > tol)
        throw std::invalid_argument(what + ": last row must be 0 0 0 1");
    const Eigen::Matrix3d R = M.topLeftCorner<3, 3>();
    if ((R.transpose() * R - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff() > tol)
        throw std::invalid_argument(what + ": rotation part is not orthonormal");
    if (R.determinant() <= 0) throw std::invalid_argument(what + ": rotation part has determinant <= 0");
    Eigen::JacobiSVD<Eigen::Matrix3d> svd(R, Eigen::ComputeFullU | Eigen::ComputeFullV);
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
    T.linear() = svd.matrixU() * svd.matrixV().transpose();
    T.translation() = M.topRightCorner<3, 1>();
    return T;
}

Eigen::Isometry3d rotation_about_line(const Eigen::Vector3d& point, const Eigen::Vector3d& direction,
                                      double angle_deg) {
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
    T.linear() = Eigen::AngleAxisd(angle_deg * kDeg, direction.normalized()).toRotationMatrix();
    T.translation() = point - T.linear() * point;
    return T;
}

double wrap_deg(double a) {
    a = std::fmod(a, 360.0);
    if (a > 180.0) a -= 360.0;
    if (a <= -180.0) a += 360.0;
    return a;
}

double rotation_angle_deg(const Eigen::Matrix3d& R) {
    const double c = std::clamp((R.trace() - 1.0) / 2.0, -1.0, 1.0);
    return std::acos(c) / kDeg;
}

PoseError pose_error(const Eigen::Isometry3d& a, const Eigen::Isometry3d& b) {
    return {(a.translation() - b.translation()).norm(),
            rotation_angle_deg(a.linear().transpose() * b.linear())};
}

Eigen::Matrix3d skew(const Eigen::Vector3d& v) {
    Eigen::Matrix3d m;
    m << 0, -v.z(), v.y(), v.z(), 0, -v.x(), -v.y(), v.x(), 0;
    return m;
}

Eigen::Matrix3d shift_covariance_at(const Matrix6d& twist_cov, const Eigen::Vector3d& p) {
    Eigen::Matrix<double, 3, 6> J;  // shift at p = v + w x p = -[p]x w + v
    J << -skew(p), Eigen::Matrix3d::Identity();
    return J * twist_cov * J.transpose();
}

double least_share(const Matrix6d& part, const Matrix6d& whole) {
    // whole = L L^T; part u = mu whole u  <=>  (L^-1 part L^-T) y = mu y with y = L^T u.
    const Eigen::LLT<Matrix6d> llt(whole);
    if (llt.info() != Eigen::Success) return 0.0;
    const Eigen::Matrix<double, 6, 6> L = llt.matrixL();
    const Matrix6d a =
        L.triangularView<Eigen::Lower>().solve(L.triangularView<Eigen::Lower>().solve(part).transpose());
    const Eigen::SelfAdjointEigenSolver<Matrix6d> es(0.5 * (a + a.transpose()), Eigen::EigenvaluesOnly);
    return std::clamp(es.eigenvalues()(0), 0.0, 1.0);
}

}  // namespace partloc
