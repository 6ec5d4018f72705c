#pragma once
// Machine axes (SPEC "Machine axes"): a body carried by axes 1..n (base first) sits at axis values q at
//   T(q) = M_1(q_1) * ... * M_n(q_n) * T(0),
// where M_i is axis i's motion, its geometry given with every axis at 0.
#include <Eigen/Geometry>
#include <map>
#include <string>
#include <vector>

namespace partloc {

enum class AxisType { Linear, Rotary };

struct Axis {
    std::string name;
    AxisType type = AxisType::Linear;
    Eigen::Vector3d direction = Eigen::Vector3d::UnitX();  ///< unit vector, machine frame
    Eigen::Vector3d point = Eigen::Vector3d::Zero();       ///< a point on a rotary axis' line (job units)

    /// M(q): translation by q * direction (job units) or rotation by q degrees about the line.
    Eigen::Isometry3d motion(double q) const;
};

/// Axis positions by axis name; a missing axis is at 0. Linear in job units, rotary in degrees.
using AxisValues = std::map<std::string, double>;

struct Machine {
    std::vector<Axis> axes;

    const Axis* find(const std::string& name) const;

    /// M_1(q_1) * ... * M_n(q_n) for the axes `chain` (base first). Throws std::invalid_argument on an
    /// axis name the machine does not have.
    Eigen::Isometry3d motion(const std::vector<std::string>& chain, const AxisValues& q) const;
};

}  // namespace partloc
