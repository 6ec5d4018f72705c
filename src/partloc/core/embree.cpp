#include "partloc/core/embree.hpp"

#include <limits>
#include <mutex>
#include <stdexcept>
#include <string>

namespace partloc::embree {

RTCDevice device() {
    static std::once_flag once;
    static RTCDevice d = nullptr;
    std::call_once(once, [] {
        d = rtcNewDevice(nullptr);
        if (!d) throw std::runtime_error("Embree: could not create a device");
    });
    return d;
}

void check(const char* what) {
    const RTCError e = rtcGetDeviceError(device());
    if (e != RTC_ERROR_NONE)
        throw std::runtime_error(std::string("Embree: ") + what + " failed (error " +
                                 std::to_string(static_cast<int>(e)) + ")");
}

void attach_triangles(RTCScene scene, const std::vector<Eigen::Vector3d>& V,
                      const std::vector<Eigen::Vector3i>& triangles, unsigned id) {
    RTCGeometry geom = rtcNewGeometry(device(), RTC_GEOMETRY_TYPE_TRIANGLE);
    auto* vb = static_cast<float*>(rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3,
                                                           3 * sizeof(float), V.size()));
    auto* ib = static_cast<unsigned*>(rtcSetNewGeometryBuffer(
        geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, 3 * sizeof(unsigned), triangles.size()));
    if (!vb || !ib) {
        rtcReleaseGeometry(geom);
        check("allocating a geometry buffer");
        throw std::runtime_error("Embree: could not allocate a geometry buffer");
    }
    for (std::size_t i = 0; i < V.size(); ++i)
        for (int k = 0; k < 3; ++k) vb[3 * i + k] = static_cast<float>(V[i][k]);
    for (std::size_t t = 0; t < triangles.size(); ++t)
        for (int k = 0; k < 3; ++k) ib[3 * t + k] = static_cast<unsigned>(triangles[t][k]);
    rtcCommitGeometry(geom);
    rtcAttachGeometryByID(scene, geom, id);
    rtcReleaseGeometry(geom);
}

RTCRay ray(const Eigen::Vector3d& origin, const Eigen::Vector3d& direction) {
    RTCRay r;
    r.org_x = static_cast<float>(origin.x());
    r.org_y = static_cast<float>(origin.y());
    r.org_z = static_cast<float>(origin.z());
    r.dir_x = static_cast<float>(direction.x());
    r.dir_y = static_cast<float>(direction.y());
    r.dir_z = static_cast<float>(direction.z());
    r.tnear = 0.0f;
    r.tfar = std::numeric_limits<float>::infinity();
    r.time = 0.0f;
    r.mask = static_cast<unsigned>(-1);  // Debian's Embree tests the mask: 0 would hit nothing
    r.id = 0;
    r.flags = 0;
    return r;
}

}  // namespace partloc::embree
