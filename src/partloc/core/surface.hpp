#pragma once
// Oriented surface samples with a search structure built once, shared by the fine fit and the verification.
#include <open3d/geometry/PointCloud.h>
#include <open3d/geometry/TriangleMesh.h>

#include <Eigen/Core>
#include <limits>
#include <memory>
#include <vector>

#include "partloc/core/nearest_map.hpp"
#include "partloc/core/sample_grid.hpp"

namespace partloc {

/// Points with unit normals and an exact nearest-sample search over them. Build once, query from many
/// threads.
struct Surface {
    std::vector<Eigen::Vector3d> points;
    std::vector<Eigen::Vector3d> normals;
    std::shared_ptr<open3d::geometry::PointCloud> cloud;  ///< the same points, for Open3D calls
    SampleGrid grid;  ///< the fast exact search the fits use (sample_grid.hpp); empty for a composed surface
    /// A surface composed of other surfaces at rigid poses (make_pose_target: the fiducials where they are
    /// in the machine): its samples are theirs, part after part, moved to this frame, and the search asks
    /// each part's own grid. The parts must outlive this surface.
    struct Part {
        const Surface* surface = nullptr;
        Eigen::Isometry3d T_part_this = Eigen::Isometry3d::Identity();  ///< this frame -> the part's
        int first = 0;  ///< index of the part's first sample among this surface's
    };
    std::vector<Part> parts;
    /// Approximate search for the coarse stages of a fit (nearest_map.hpp); null unless add_coarse_map ran.
    /// Shared by copies of the surface, which keep the same samples.
    std::shared_ptr<const NearestMap> coarse;
    Eigen::Vector3d center = Eigen::Vector3d::Zero();  ///< centre of the bounding box
    double diameter = 0.0;                             ///< bounding-box diagonal (job units)
    double spacing = 0.0;                              ///< typical distance between samples (job units)

    /// Index of the nearest sample and its squared distance; -1 when the surface is empty or no sample lies
    /// within max_distance (a bound makes far queries cheap: the grid search stops at it).
    int nearest(const Eigen::Vector3d& p, double* squared_distance,
                double max_distance = std::numeric_limits<double>::infinity()) const;
    /// The up to k (<= SampleGrid::kMaxK) nearest samples within max_distance of p, nearest first: indices
    /// and squared distances. Returns how many were found.
    int nearest(const Eigen::Vector3d& p, int k, double max_distance, int* indices,
                double* squared_distances) const;
    /// The squared distance from p to sample `index`, computed as nearest() computes it (in the part's frame
    /// for a composed surface), to the bit.
    double squared_distance(const Eigen::Vector3d& p, int index) const;
};

/// Surface::nearest for a fixed set of points that move a little between queries: the iterations of a fit.
/// Each point keeps the samples nearest to where it was last looked up (kListed of them, or all within the
/// reach), and the bound that every other sample lay beyond. Asked again from a point that has moved by d,
/// the kept samples answer when the k-th nearest of them (by the distances from the new position) is nearer
/// than the bound less d; otherwise the grid is searched again. The answer is exactly Surface::nearest's:
/// the same samples, the same squared distances (computed as the search computes them), nearest first.
///
/// Ours: neither Open3D nor nanoflann keeps a search's neighbours across queries. Seed 106 makes 4.8 million
/// exact queries in its fits, 4.1 million of them past a fit's first iteration, when the pose has moved
/// little; 3.5 million are answered from the kept samples (`partloc_bench nearest` times both).
class NearestCache {
  public:
    static constexpr int kListed = 6;
    /// For `points` query points, searching within `reach` (at least every max_distance asked for).
    NearestCache(const Surface& surface, std::size_t points, double reach);
    /// Surface::nearest(p, k, max_distance, ...) for query point i (k < kListed, max_distance <= reach).
    /// Query points may be asked from several threads, each point from one at a time.
    int nearest(std::size_t i, const Eigen::Vector3d& p, int k, double max_distance, int* indices,
                double* squared_distances);
    double reach() const { return reach_; }
    /// Grid searches made so far (the rest were answered from the kept samples). Not while querying.
    std::size_t searches() const;

  private:
    struct Entry {
        Eigen::Vector3d at;  ///< where the samples were looked up
        double bound = 0.0;  ///< every sample not listed lay at least this far from `at`
        int listed = -1;     ///< -1: not looked up yet
        int index[kListed];
        std::uint32_t searches = 0;
    };
    const Surface& surface_;
    double reach_;
    std::vector<Entry> entries_;
};

/// Gives `surface` an approximate search (Surface::coarse) with cells of `cell`, answering within `reach`.
void add_coarse_map(Surface& surface, double cell, double reach);

/// Builds a Surface from points that carry normals (throws std::invalid_argument without normals).
Surface make_surface(std::shared_ptr<open3d::geometry::PointCloud> cloud, double spacing);
/// The same with the search grid built before for these points and spacing (Surface::grid of it).
Surface make_surface(std::shared_ptr<open3d::geometry::PointCloud> cloud, double spacing, SampleGrid grid);
/// The surfaces `parts` at poses `T_this_part` as one surface (Surface::parts), without a grid of its own: a
/// grid over fiducials spread across a machine spans mostly empty space (seed 106: 0.5 s of a job's 12 s of
/// CPU went to building such grids, one per scan and per fiducial fit). The parts must outlive it.
Surface compose_surfaces(const std::vector<const Surface*>& parts,
                         const std::vector<Eigen::Isometry3d>& T_this_part);

/// Paper §3.2 step 5 (MeshLab's Poisson-disk filter): samples the mesh surface with Poisson-disk sampling,
/// about one sample per `spacing`^2 of surface and no two closer than 0.8 `spacing`, with the triangles' own
/// normals (outward for a closed mesh). Deterministic. `triangles`, when given, receives each sample's
/// triangle.
std::shared_ptr<open3d::geometry::PointCloud> sample_mesh(const open3d::geometry::TriangleMesh& mesh,
                                                          double spacing,
                                                          std::vector<int>* triangles = nullptr);

/// Total area of a mesh's triangles.
double mesh_area(const open3d::geometry::TriangleMesh& mesh);

}  // namespace partloc
