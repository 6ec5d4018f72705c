#include "partloc/pipeline/job.hpp"

#include <stdexcept>

#include "partloc/core/surface.hpp"

namespace partloc {

double millimetres_per_unit(const std::string& units) {
    if (units == "mm") return 1.0;
    if (units == "m") return 1000.0;
    if (units == "in") return 25.4;
    if (units == "cm") return 10.0;
    if (units == "um") return 0.001;
    throw std::invalid_argument("unknown unit '" + units + "' (known: mm, m, in, cm, um)");
}

Eigen::AlignedBox3d bounding_box(const ModelSource& m) {
    Eigen::AlignedBox3d box;
    if (m.mesh)
        for (const auto& v : m.mesh->vertices_) box.extend(v);
    if (m.points)
        for (const auto& v : m.points->points_) box.extend(v);
    return box;
}

Eigen::Isometry3d fiducial_at(const Machine& machine, const Fiducial& f, const AxisValues& q) {
    return machine.motion(f.moves_with, q) * machine.motion(f.moves_with, f.probed_at).inverse() *
           f.T_machine_fiducial;
}

Eigen::AlignedBox3d workpiece_region(const Job& job, double spacing) {
    if (job.workpiece.region) return *job.workpiece.region;
    Eigen::AlignedBox3d region = bounding_box(job.workpiece.reference_surfaces);
    if (job.workpiece.final_part) region.extend(bounding_box(*job.workpiece.final_part));
    const double margin = 0.15 * region.diagonal().norm() + 5.0 * spacing;
    region.min() -= Eigen::Vector3d::Constant(margin);
    region.max() += Eigen::Vector3d::Constant(margin);
    return region;
}

double default_pose_sigma(const std::string& units) { return 0.005 / millimetres_per_unit(units); }

ModelSource union_of_datums(const std::vector<Datum>& datums) {
    ModelSource u;
    if (datums.empty()) return u;
    u.file = "datums";
    bool all_meshes = true;
    Eigen::AlignedBox3d box;
    for (const auto& d : datums) {
        all_meshes = all_meshes && d.surfaces.mesh;
        if (d.surfaces.mesh)
            for (const auto& v : d.surfaces.mesh->vertices_) box.extend(v);
        if (d.surfaces.points)
            for (const auto& v : d.surfaces.points->points_) box.extend(v);
    }
    if (all_meshes) {
        auto mesh = std::make_shared<open3d::geometry::TriangleMesh>();
        for (const auto& d : datums) *mesh += *d.surfaces.mesh;
        u.mesh = mesh;
        return u;
    }
    auto cloud = std::make_shared<open3d::geometry::PointCloud>();
    bool normals = true;
    const double spacing = std::max(box.diagonal().norm() / 400.0, 1e-12);
    for (const auto& d : datums) {
        const auto part = d.surfaces.mesh ? sample_mesh(*d.surfaces.mesh, spacing) : d.surfaces.points;
        if (!part) continue;
        normals = normals && part->HasNormals();
        cloud->points_.insert(cloud->points_.end(), part->points_.begin(), part->points_.end());
        if (normals)
            cloud->normals_.insert(cloud->normals_.end(), part->normals_.begin(), part->normals_.end());
    }
    if (!normals) cloud->normals_.clear();
    u.points = cloud;
    return u;
}

}  // namespace partloc
