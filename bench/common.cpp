#include "common.hpp"

#include <sys/resource.h>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <stdexcept>
#include <string>

#include "partloc/core/geometry.hpp"
#include "partloc/core/surface.hpp"

namespace partloc::bench {

sim::SimulatedJob make_cell(const CellSpec& spec) {
    sim::ScenarioOptions o;
    o.scanner.point_spacing = spec.spacing;
    o.scanner.noise_sigma = spec.noise;
    o.a_values.clear();
    for (int k = 0; k < spec.positions; ++k)
        o.a_values.push_back(spec.positions == 1 ? 0.0 : 90.0 * k / (spec.positions - 1));
    o.scans_per_position = spec.per_position;
    return sim::simulate_random_cell(spec.seed, o);
}

bool registered_right(const Eigen::Isometry3d& T_machine_scan, const sim::SimulatedJob& cell,
                      std::size_t scan) {
    const Eigen::Vector3d at = cell.truth.T_machine_workpiece.translation();
    const Eigen::Isometry3d D = T_machine_scan * cell.truth.scans[scan].T_machine_scan.inverse();
    return (D * at - at).norm() < 0.5 && rotation_angle_deg(D.linear()) < 0.2;
}

bool fiducial_in_view(const sim::SimulatedJob& cell, std::size_t scan) {
    std::size_t seen = 0;
    for (const auto& [name, n] : cell.truth.scans[scan].fiducial_points) seen = std::max(seen, n);
    return seen >= kSeenPoints;
}

Verdict judge(const MethodOutcome& outcome, const sim::SimulatedJob& cell) {
    Verdict v;
    for (std::size_t i = 0; i < outcome.T_machine_scan.size() && i < cell.truth.scans.size(); ++i) {
        if (!outcome.T_machine_scan[i]) {
            ++v.rejected;
            continue;
        }
        (registered_right(*outcome.T_machine_scan[i], cell, i) ? v.right : v.wrong) += 1;
    }
    if (outcome.located) {
        v.located = true;
        const PoseError e = pose_error(outcome.T_machine_workpiece, cell.truth.T_machine_workpiece);
        v.origin_mm = e.translation;
        v.rotation_deg = e.rotation_deg;
    }
    return v;
}

Eigen::Isometry3d T_machine0_scan(const Job& job, const Scan& scan, const Eigen::Isometry3d& T_machine_scan) {
    return job.machine.motion(job.workpiece.moves_with, scan.axes).inverse() * T_machine_scan;
}

std::shared_ptr<open3d::geometry::PointCloud> fiducial_points(const Fiducial& f, double spacing,
                                                              bool feature_only) {
    std::shared_ptr<open3d::geometry::PointCloud> all;
    if (f.model.mesh) {
        all = sample_mesh(*f.model.mesh, spacing);
    } else if (f.model.points) {
        all = std::make_shared<open3d::geometry::PointCloud>(*f.model.points);
        if (!all->HasNormals()) all->EstimateNormals();
    } else {
        throw std::invalid_argument("fiducial " + f.name + ": model has neither mesh nor points");
    }
    auto out = std::make_shared<open3d::geometry::PointCloud>();
    const Eigen::Matrix3d R = f.T_machine_fiducial.linear();
    for (std::size_t i = 0; i < all->points_.size(); ++i) {
        const Eigen::Vector3d& p = all->points_[i];
        const Eigen::Vector3d& n = all->normals_[i];
        if ((R * n).z() < -0.9) continue;  // stands on it: never seen
        if (feature_only) {
            bool on = false;
            for (int a = 0; a < 3; ++a)
                on = on || (std::abs(p[a]) < 1e-3 * (1.0 + p.norm()) && std::abs(n[a]) > 0.99);
            if (!on) continue;
        }
        out->points_.push_back(all->points_[i]);
        out->normals_.push_back(all->normals_[i]);
    }
    return out;
}

std::shared_ptr<open3d::geometry::PointCloud> reference_points(const Job& job, double spacing) {
    const auto& ref = job.workpiece.reference_surfaces;
    if (ref.mesh && !ref.mesh->triangles_.empty()) return sample_mesh(*ref.mesh, spacing);
    if (ref.points) {
        auto p = std::make_shared<open3d::geometry::PointCloud>(*ref.points);
        if (!p->HasNormals()) p->EstimateNormals();
        return p;
    }
    throw std::invalid_argument("the reference surfaces are empty");
}

double fiducial_diagonal(const Job& job) {
    double d = 0.0;
    for (const auto& f : job.fiducials) d = std::max(d, bounding_box(f.model).diagonal().norm());
    return d;
}

namespace {
double status_field_mib(const char* key) {
    std::ifstream in("/proc/self/status");
    std::string line;
    const std::string k = std::string(key) + ":";
    while (std::getline(in, line))
        if (line.rfind(k, 0) == 0) return std::stod(line.substr(k.size())) / 1024.0;  // kB
    return -1.0;
}
}  // namespace

bool reset_peak_memory() {
    std::ofstream out("/proc/self/clear_refs");
    if (!out) return false;
    out << "5";
    return static_cast<bool>(out);
}

double peak_memory_mib() {
    const double hwm = status_field_mib("VmHWM");
    if (hwm > 0) return hwm;
    rusage ru{};
    getrusage(RUSAGE_SELF, &ru);
    return ru.ru_maxrss / 1024.0;
}

double current_memory_mib() { return status_field_mib("VmRSS"); }

double seconds_since(std::chrono::steady_clock::time_point t0) {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

}  // namespace partloc::bench
