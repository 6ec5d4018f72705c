#include "partloc/core/visible_surface.hpp"

#include <embree3/rtcore.h>
#include <tbb/parallel_for.h>

#include <cmath>
#include <limits>
#include <mutex>
#include <stdexcept>
#include <string>

namespace partloc {

namespace {

/// One Embree device for the process, created on first use.
RTCDevice device() {
    static std::once_flag once;
    static RTCDevice d = nullptr;
    std::call_once(once, [] { d = rtcNewDevice(nullptr); });
    if (!d) throw std::runtime_error("Embree: could not create a device");
    return d;
}

/// The mesh as an Embree scene (float: the offset below is far above its precision).
class Scene {
  public:
    explicit Scene(const open3d::geometry::TriangleMesh& mesh) {
        scene_ = rtcNewScene(device());
        RTCGeometry geom = rtcNewGeometry(device(), RTC_GEOMETRY_TYPE_TRIANGLE);
        auto* vb = static_cast<float*>(rtcSetNewGeometryBuffer(
            geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, 3 * sizeof(float), mesh.vertices_.size()));
        auto* ib = static_cast<unsigned*>(rtcSetNewGeometryBuffer(
            geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, 3 * sizeof(unsigned), mesh.triangles_.size()));
        if (!vb || !ib) {
            rtcReleaseGeometry(geom);
            rtcReleaseScene(scene_);
            throw std::runtime_error("Embree: could not allocate a geometry buffer");
        }
        for (std::size_t i = 0; i < mesh.vertices_.size(); ++i)
            for (int k = 0; k < 3; ++k) vb[3 * i + k] = static_cast<float>(mesh.vertices_[i][k]);
        for (std::size_t t = 0; t < mesh.triangles_.size(); ++t)
            for (int k = 0; k < 3; ++k) ib[3 * t + k] = static_cast<unsigned>(mesh.triangles_[t][k]);
        rtcCommitGeometry(geom);
        rtcAttachGeometry(scene_, geom);
        rtcReleaseGeometry(geom);
        rtcCommitScene(scene_);
    }
    ~Scene() { rtcReleaseScene(scene_); }
    Scene(const Scene&) = delete;
    Scene& operator=(const Scene&) = delete;

    /// Whether the ray from o along the unit vector d hits the mesh.
    bool occluded(const Eigen::Vector3d& o, const Eigen::Vector3d& d) const {
        RTCIntersectContext context;
        rtcInitIntersectContext(&context);
        RTCRay ray;
        ray.org_x = static_cast<float>(o.x());
        ray.org_y = static_cast<float>(o.y());
        ray.org_z = static_cast<float>(o.z());
        ray.dir_x = static_cast<float>(d.x());
        ray.dir_y = static_cast<float>(d.y());
        ray.dir_z = static_cast<float>(d.z());
        ray.tnear = 0.0f;
        ray.tfar = std::numeric_limits<float>::infinity();
        ray.time = 0.0f;
        ray.mask = static_cast<unsigned>(-1);  // Debian's Embree tests the mask: 0 would hit nothing
        ray.id = 0;
        ray.flags = 0;
        rtcOccluded1(scene_, &context, &ray);
        return ray.tfar < 0.0f;  // Embree marks an occluded ray with tfar = -inf
    }

  private:
    RTCScene scene_ = nullptr;
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
