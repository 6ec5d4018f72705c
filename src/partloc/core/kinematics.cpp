#include "partloc/core/kinematics.hpp"

#include <stdexcept>

#include "partloc/core/geometry.hpp"

namespace partloc {

Eigen::Isometry3d Axis::motion(double q) const {
    if (type == AxisType::Rotary) return rotation_about_line(point, direction, q);
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
    T.translation() = q * direction.normalized();
    return T;
}

const Axis* Machine::find(const std::string& name) const {
    for (const auto& a : axes)
        if (a.name == name) return &a;
    return nullptr;
}

Eigen::Isometry3d Machine::motion(const std::vector<std::string>& chain, const AxisValues& q) const {
    Eigen::Isometry3d M = Eigen::Isometry3d::Identity();
    for (const auto& name : chain) {
        const Axis* axis = find(name);
        if (!axis)
            throw std::invalid_argument("moves_with names axis '" + name + "' that machine.axes lacks");
        const auto it = q.find(name);
        M = M * axis->motion(it == q.end() ? 0.0 : it->second);
    }
    return M;
}

}  // namespace partloc
