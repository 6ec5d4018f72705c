#pragma once
// What every caller of Embree 3 needs (called directly: Open3D's raycaster returns no hits with Debian's
// build): one device for the process, its errors as exceptions, a mesh attached to a scene, and a ray set
// up the way Debian's build needs it.
#include <embree3/rtcore.h>

#include <Eigen/Core>
#include <vector>

namespace partloc::embree {

/// One Embree device for the process, created on first use; throws std::runtime_error if it cannot be.
RTCDevice device();

/// Throws std::runtime_error naming `what` when the device reports an error.
void check(const char* what);

/// Attaches the triangles (vertices V, in float) to `scene` as geometry `id`; throws std::runtime_error when
/// Embree cannot allocate them.
void attach_triangles(RTCScene scene, const std::vector<Eigen::Vector3d>& V,
                      const std::vector<Eigen::Vector3i>& triangles, unsigned id);

/// A ray from `origin` along the unit vector `direction`, from 0 to infinity, seen by every geometry.
RTCRay ray(const Eigen::Vector3d& origin, const Eigen::Vector3d& direction);

}  // namespace partloc::embree
