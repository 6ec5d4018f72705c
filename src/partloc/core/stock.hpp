#pragma once
// The as-built stock model for CAM (paper §3.4.2, Fig. 9a): a triangulated surface of the merged points.
//
// Our own reconstruction instead of Open3D's screened Poisson, which cost 1.3-1.5 s on one thread for a demo
// job whatever the points (octree depth 8), 5.3-6.4 s at depth 9, the largest serial part of the job. The
// surface is the zero set of an implicit function of the oriented points (an IMLS signed distance: the
// weighted mean of the points' tangent-plane distances, Kolluri 2008, sharpened at edges by one robust-IMLS
// reweighting), defined only where enough points support it, evaluated on the corners of the grid cells it
// crosses (found outward from the cells that hold points; a sparse grid, nothing dense over the box) and
// triangulated by surface nets (a vertex per crossed cell, a quad per crossed grid edge). Seed 106's merged
// points, one thread (`partloc_bench stock`, bench/stock.cpp): 0.12 s against Poisson's 1.3 s, vertices
// closer to the true surface (median 0.013 against 0.020 mm, 95th percentile 0.052 against 0.144, max 0.53
// against 2.8), the scanned surface as closely followed (95th percentile 0.052 against 0.061 mm), open where
// nothing was scanned; at a scanner spacing of 0.135 mm 0.27 s against 6.4 s. tests/test_stock.cpp checks
// distance to known shapes, orientation, coverage and holes.
#include <open3d/geometry/PointCloud.h>
#include <open3d/geometry/TriangleMesh.h>

#include <memory>

namespace partloc {

// The defaults measured best on seed 106 at scanner spacings 0.383 and 0.135 mm (partloc_bench stock --sweep;
// cover = scanned surface within two spacings of the stock): cells of one spacing took twice the time for 2.3
// times the triangles and about the same accuracy; cells of two lost cover (0.9852 against 0.9923, 0.961
// against 0.971). A reach of 3 spacings lost cover where the points are sparse (0.135 mm: 0.956), 5 rounded
// the edges (0.383 mm: vertices' 95th percentile 0.068 against 0.052 mm). Less support grew the stock past
// its points (0.05: farthest vertex 0.70 against 0.53 mm), more left holes at the edges of scanned patches
// (0.15: cover 0.964, 0.3: 0.909, at 0.135 mm).
struct StockSettings {
    /// Scanner's point spacing (job units). The lengths below are in the points' own spacing on their
    /// surface, measured from it (the merged points are sparser: run.cpp strides them to 150 k before
    /// thinning).
    double spacing = 0.0;
    double voxel = 1.5;   ///< edge of the grid's cells, in spacings
    double radius = 4.0;  ///< reach of a point's weight (compact support), in spacings
    /// A grid corner is defined where the weight of the surface nearest to it is at least this fraction of
    /// what a flat surface with one point per spacing^2 has; elsewhere the stock stays open (nothing scanned
    /// there).
    double min_support = 0.1;
    double density_quantile = 0.03;  ///< build_stock_poisson: the vertices supported by the fewest points go
};

/// The stock: the zero set of the points' IMLS distance (above), closed where the points close it and open
/// where nothing was scanned, triangles facing the side the points' normals face, with triangle normals.
/// Needs unit normals; returns an empty mesh when the points are too few (< 100) or have none, and throws
/// std::invalid_argument when settings.spacing is not > 0. The same bits for any number of threads.
std::shared_ptr<open3d::geometry::TriangleMesh> build_stock(const open3d::geometry::PointCloud& points,
                                                            const StockSettings& settings);

/// The stock as it was built before: screened Poisson reconstruction (Open3D, one thread), trimmed where few
/// points support it and to the points' bounding box. Kept for `partloc_bench stock`, which compares them.
std::shared_ptr<open3d::geometry::TriangleMesh> build_stock_poisson(
    const open3d::geometry::PointCloud& points, const StockSettings& settings);

}  // namespace partloc
