#pragma once
// The part of a model's surface a scanner can see: CAD exports of several bodies keep faces inside the
// solid (overlapping boxes, bodies that touch, a body sunk into another, a body exported twice), and a
// model sampled on them offers the fit surfaces that no scan can show: a face of the scan matched to an
// internal face a millimetre behind the real one is a fit slid by that millimetre, and verification counts
// the internal faces as surface the scan should have seen (issue 25: world 2's stepped blocks and
// multi-body brackets).
#include <open3d/geometry/TriangleMesh.h>

#include <Eigen/Core>
#include <vector>

namespace partloc {

struct VisibilitySettings {
    int directions = 64;  ///< rays per side of each sample, spread over the sphere (Fibonacci)
    /// Rays start this far off the surface on either side, times the mesh's bounding-box diagonal: far
    /// enough that Embree's float precision does not hit the sample's own face, well inside a wall.
    double offset = 1e-4;
};

/// For each point on the mesh's surface (with its normal, either sign), whether it can be seen from outside
/// the mesh: some ray from just off it, on one side or the other, leaves without hitting the mesh. A point
/// on an internal face is hidden on both sides. Rays are cast with Embree; an empty mesh hides nothing.
std::vector<char> visible_from_outside(const open3d::geometry::TriangleMesh& mesh,
                                       const std::vector<Eigen::Vector3d>& points,
                                       const std::vector<Eigen::Vector3d>& normals,
                                       const VisibilitySettings& settings = {});

}  // namespace partloc
