#include "partloc/core/surface.hpp"

#include <open3d/geometry/BoundingVolume.h>

#include <cmath>
#include <stdexcept>

namespace partloc {

int Surface::nearest(const Eigen::Vector3d& p, double* squared_distance) const {
    std::vector<int> idx(1);
    std::vector<double> d2(1);
    if (points.empty() || tree->SearchKNN(p, 1, idx, d2) < 1) return -1;
    if (squared_distance) *squared_distance = d2[0];
    return idx[0];
}

Surface make_surface(std::shared_ptr<open3d::geometry::PointCloud> cloud, double spacing) {
    if (!cloud->HasNormals()) throw std::invalid_argument("surface samples need normals");
    Surface s;
    s.cloud = cloud;
    s.points = cloud->points_;
    s.normals = cloud->normals_;
    for (auto& n : s.normals) n.normalize();
    s.tree = std::make_shared<open3d::geometry::KDTreeFlann>(*cloud);
    if (!s.points.empty()) {
        const auto box = cloud->GetAxisAlignedBoundingBox();
        s.center = box.GetCenter();
        s.diameter = (box.max_bound_ - box.min_bound_).norm();
    }
    s.spacing = spacing;
    return s;
}

double mesh_area(const open3d::geometry::TriangleMesh& mesh) {
    double area = 0.0;
    for (const auto& t : mesh.triangles_) {
        const Eigen::Vector3d& a = mesh.vertices_[t(0)];
        area += 0.5 * (mesh.vertices_[t(1)] - a).cross(mesh.vertices_[t(2)] - a).norm();
    }
    return area;
}

std::shared_ptr<open3d::geometry::PointCloud> sample_mesh(const open3d::geometry::TriangleMesh& mesh,
                                                          double spacing) {
    if (mesh.triangles_.empty()) throw std::invalid_argument("mesh has no triangles");
    // A Poisson-disk set of radius r covers the area with about one sample per 0.7 r^2 (hexagonal packing
    // of discs of radius r/2 has one sample per (sqrt(3)/2) r^2).
    const double area = mesh_area(mesh);
    const auto n = static_cast<std::size_t>(std::max(100.0, area / (0.866 * spacing * spacing)));
    open3d::geometry::TriangleMesh copy(mesh);
    copy.ComputeTriangleNormals();
    auto cloud = copy.SamplePointsPoissonDisk(n, 3.0, nullptr, true);
    return cloud;
}

}  // namespace partloc
