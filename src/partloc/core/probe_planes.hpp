#pragma once
// A frame from probed points on three planes, as the paper took the fiducials' and the workpiece's poses
// (§3.2 and §4: "three data points on each reference plane ... the (least squares) point simultaneously
// closest to all three planes"). The points are probe contact points already compensated for the stylus
// radius, in the machine frame.
//
// Convention (it matches how the models are built: the datum corner at the origin, the three datum planes
// x = 0, y = 0, z = 0 of the model frame, see sim::corner_frame):
//   - plane i (0, 1, 2) is the model's x = 0, y = 0, z = 0 plane: its normal is the frame's axis i;
//   - each normal points to the side where the other two planes' points lie, i.e. from the corner along the
//     edges, into the octant the corner opens to (for a concave corner, the air the probe came from);
//   - the three signed normals, in this order, must form a right-handed frame; the rotation is the nearest
//     rotation to [n0 n1 n2] (SVD), the origin the point closest to the three fitted planes.
#include <Eigen/Geometry>
#include <array>
#include <string>
#include <vector>

namespace partloc {

struct ProbePlaneSettings {
    /// A plane whose RMS residual exceeds this fraction of its points' extent is rejected (a point from
    /// another face, a typing error); a probed, machined plane is flat to far better than 1 %.
    double max_rms_fraction = 0.01;
    /// Points spread less than this fraction of their length across it are collinear: no plane.
    double min_width_fraction = 0.02;
    double min_angle_deg = 30.0;             ///< two normals closer to parallel than this are rejected
    double max_nonorthogonality_deg = 10.0;  ///< a normal further than this from its orthonormal axis
};

struct PlaneFit {
    Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();  ///< unit, signed by the convention above
    double offset = 0.0;                                ///< the plane is normal . x = offset (job units)
    std::size_t points = 0;
    double rms = 0.0;     ///< RMS distance of the points to the plane (job units)
    double max = 0.0;     ///< largest distance of a point to the plane (job units)
    double extent = 0.0;  ///< largest distance between two of the points (job units)
};

struct ProbedFrame {
    bool valid = false;
    std::string reason;  ///< why not, when not valid
    int plane = -1;      ///< the plane the reason is about (0, 1, 2), or -1 when about the three together
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();  ///< T_machine_frame
    std::array<PlaneFit, 3> planes;
    double nonorthogonality_deg = 0.0;  ///< largest angle between a fitted normal and its frame axis
};

/// Fits a plane to each list (least squares, three or more points each), signs the normals and builds the
/// frame as described above. A failure is a result with a reason, never a throw.
ProbedFrame frame_from_probe_planes(const std::array<std::vector<Eigen::Vector3d>, 3>& planes,
                                    const ProbePlaneSettings& settings = {});

}  // namespace partloc
