#pragma once
// The as-built stock model for CAM (paper §3.4.2, Fig. 9a): a triangulated surface of the merged points.
#include <open3d/geometry/PointCloud.h>
#include <open3d/geometry/TriangleMesh.h>

#include <memory>

namespace partloc {

struct StockSettings {
    double spacing = 0.0;              ///< point spacing (job units); sets the reconstruction depth
    double density_quantile = 0.03;    ///< vertices supported by the fewest points are trimmed off
};

/// Screened Poisson reconstruction (Open3D) of oriented points, trimmed where few points support it and to
/// the points' bounding box. Returns an empty mesh when the points are too few.
std::shared_ptr<open3d::geometry::TriangleMesh> build_stock(const open3d::geometry::PointCloud& points,
                                                            const StockSettings& settings);

}  // namespace partloc
