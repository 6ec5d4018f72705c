#include "partloc/core/visible_surface.hpp"

#include <tbb/parallel_for.h>

#include <cmath>

#include "partloc/core/embree.hpp"

namespace partloc {

namespace {

/// The mesh as an Embree scene (float: the offset below is far above its precision).
class Scene {
  public:
    explicit Scene(const open3d::geometry::TriangleMesh& mesh) : scene_(rtcNewScene(embree::device())) {
        try {
            embree::attach_triangles(scene_, mesh.vertices_, mesh.triangles_, 0);
        } catch (...) {
            rtcReleaseScene(scene_);
            throw;
        }
        rtcCommitScene(scene_);
    }
    ~Scene() { rtcReleaseScene(scene_); }
    Scene(const Scene&) = delete;
    Scene& operator=(const Scene&) = delete;

    /// Whether the ray from o along the unit vector d hits the mesh.
    bool occluded(const Eigen::Vector3d& o, const Eigen::Vector3d& d) const {
        RTCIntersectContext context;
        rtcInitIntersectContext(&context);
        RTCRay ray = embree::ray(o, d);
        rtcOccluded1(scene_, &context, &ray);
        return ray.tfar < 0.0f;  // Embree marks an occluded ray with tfar = -inf
    }

  private:
    RTCScene scene_;
};

/// n directions spread evenly over the unit sphere (a Fibonacci lattice).
std::vector<Eigen::Vector3d> sphere_directions(int n) {
    std::vector<Eigen::Vector3d> d;
    const double golden = M_PI * (3.0 - std::sqrt(5.0));
    for (int i = 0; i < n; ++i) {
        const double z = 1.0 - (2.0 * i + 1.0) / n;
        const double r = std::sqrt(std::max(0.0, 1.0 - z * z));
        d.emplace_back(r * std::cos(golden * i), r * std::sin(golden * i), z);
    }
    return d;
}

}  // namespace

std::vector<char> visible_from_outside(const open3d::geometry::TriangleMesh& mesh,
                                       const std::vector<Eigen::Vector3d>& points,
                                       const std::vector<Eigen::Vector3d>& normals,
                                       const VisibilitySettings& settings) {
    std::vector<char> visible(points.size(), 1);
    if (mesh.triangles_.empty() || mesh.vertices_.empty() || normals.size() != points.size()) return visible;
    const Scene scene(mesh);
    const std::vector<Eigen::Vector3d> dirs = sphere_directions(settings.directions);
    const double offset = settings.offset * (mesh.GetMaxBound() - mesh.GetMinBound()).norm();
    tbb::parallel_for(std::size_t(0), points.size(), [&](std::size_t i) {
        const Eigen::Vector3d& n = normals[i];
        for (const double side : {1.0, -1.0}) {
            const Eigen::Vector3d o = points[i] + side * offset * n;
            for (const Eigen::Vector3d& d : dirs) {
                if (side * d.dot(n) <= 0.0) continue;  // into the sample's own face
                if (!scene.occluded(o, d)) return;     // a way out: visible
            }
        }
        visible[i] = 0;
    });
    return visible;
}

}  // namespace partloc
