#pragma once
// Frames and transforms, written once (SPEC "Frames and units"):
//   T_a_b maps coordinates in frame b to frame a:  p_a = T_a_b * p_b.
//   Frames: machine, scan, fiducial, workpiece. Lengths in the job's units, angles in degrees.
//   - machine: the machine's fixed frame. A body that no axis carries (a fixed fiducial) sits still in it;
//     T_machine_scan maps a scan into it as it was while that scan was taken (at the scan's axis values).
//   - machine0: the machine frame with every axis at its reference position (0). A body that axes carry is
//     described there (SPEC "Machine axes"): T_machine0_scan = M(q)^-1 * T_machine_scan, where M(q) is the
//     motion of the workpiece's axes at the scan's axis values q. The workpiece is reported in machine0.
//   - nominal and located: the workpiece's reference surfaces as designed (at their nominal pose in
//     machine0) and as the scans show them; T_located_nominal moves the first onto the second (the paper's R,
//     Eq. 3), so that T_machine_workpiece = T_located_nominal * T_machine_workpiece_nominal.
//   Information matrices: JtJ is the sum of J^T J over a fit's inliers, twist [w, v] (rotation first) in the
//   frame the fit names; information = JtJ / noise^2, the inverse covariance of that twist.
//   euler_xyz_deg [a, b, c] means R = Rz(c) * Ry(b) * Rx(a).
#include <Eigen/Geometry>
#include <string>

namespace partloc {

using Matrix6d = Eigen::Matrix<double, 6, 6>;
using Vector6d = Eigen::Matrix<double, 6, 1>;

/// R = Rz(c) * Ry(b) * Rx(a) for euler_deg = [a, b, c] in degrees.
Eigen::Matrix3d rotation_from_euler_xyz_deg(const Eigen::Vector3d& euler_deg);

/// Inverse of rotation_from_euler_xyz_deg; b in [-90, 90], a and c in (-180, 180].
Eigen::Vector3d euler_xyz_deg(const Eigen::Matrix3d& R);

/// Pose from an origin (job units) and euler_xyz_deg.
Eigen::Isometry3d pose_from_origin_euler(const Eigen::Vector3d& origin, const Eigen::Vector3d& euler_deg);

/// Checks that M is a rigid transform (orthonormal, det +1, last row 0 0 0 1) within tol; throws
/// std::invalid_argument naming `what` otherwise. Returns it as an isometry, re-orthonormalised.
Eigen::Isometry3d checked_isometry(const Eigen::Matrix4d& M, const std::string& what, double tol = 1e-4);

/// Rotation about the unit axis `direction` through `point` by angle_deg (right-hand rule).
Eigen::Isometry3d rotation_about_line(const Eigen::Vector3d& point, const Eigen::Vector3d& direction,
                                      double angle_deg);

/// An angle in degrees wrapped into (-180, 180].
double wrap_deg(double angle_deg);

/// Angle of the rotation R in degrees, in [0, 180].
double rotation_angle_deg(const Eigen::Matrix3d& R);

/// Difference between two poses: |t_a - t_b| (job units) and the angle of R_a^T R_b (degrees).
struct PoseError {
    double translation = 0.0;
    double rotation_deg = 0.0;
};
PoseError pose_error(const Eigen::Isometry3d& a, const Eigen::Isometry3d& b);

/// [v]x: [v]x w = v x w.
Eigen::Matrix3d skew(const Eigen::Vector3d& v);

/// Covariance of the shift of point p (v + w x p) under a small motion with twist covariance `twist_cov`
/// (twist [w, v] about the origin).
Eigen::Matrix3d shift_covariance_at(const Matrix6d& twist_cov, const Eigen::Vector3d& p);

/// The smallest share of a fit's information that a part of its points holds in any one direction: the
/// least generalised eigenvalue mu of part u = mu whole u, 0..1 (0 when `whole` is singular). The same in
/// every frame and unit, as it compares the two along each direction.
double least_share(const Matrix6d& part, const Matrix6d& whole);

}  // namespace partloc
