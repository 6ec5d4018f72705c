#pragma once
// Exact k-nearest-neighbour search on a fixed set of surface samples, for the queries the fits make millions
// of times: a few nearest samples of a point near the surface, within a distance bound.
//
// Our own because the generic KD-tree (Open3D's KDTreeFlann, nanoflann with run-time dimension and a vector
// allocation per query) spent half the run time of a job in these queries (perf, issue 3). Samples of a
// surface are evenly spread (Poisson disk), so a uniform grid with cells of about 1.5 sample spacings finds
// the k <= 8 nearest in the 27 cells around the point, and a distance transform of the occupied cells
// rejects far points in one lookup. `partloc_bench nearest` (bench/nearest.cpp) measures it against
// KDTreeFlann on the same queries: 2.8-3.1 times faster near the surface, 18-20 times for points far from it
// (BENCHMARK.md); tests/test_surface.cpp checks that it returns exactly what the KD-tree returns.
#include <Eigen/Core>
#include <Eigen/Geometry>
#include <cmath>
#include <cstdint>
#include <vector>

namespace partloc {

/// Cubic cells over a box: the frame shared by the grids of core (this one, NearestMap, RadiusGrid).
struct CellFrame {
    Eigen::Vector3d origin = Eigen::Vector3d::Zero();
    double cell = 1.0, inv_cell = 1.0;
    int nx = 0, ny = 0, nz = 0;
    CellFrame() = default;
    /// Cells of `cell` from box.min() to past box.max(); larger (by steps of 1.25) while they would number
    /// more than `max_cells`.
    CellFrame(const Eigen::AlignedBox3d& box, double cell, double max_cells);
    std::size_t count() const { return static_cast<std::size_t>(nx) * ny * nz; }
    std::size_t index(int x, int y, int z) const { return (static_cast<std::size_t>(z) * ny + y) * nx + x; }
    /// The coordinates of cell index c.
    Eigen::Array3i coordinates(std::size_t c) const {
        return {static_cast<int>(c % nx), static_cast<int>((c / nx) % ny),
                static_cast<int>(c / (static_cast<std::size_t>(nx) * ny))};
    }
    bool contains(int x, int y, int z) const {
        return x >= 0 && y >= 0 && z >= 0 && x < nx && y < ny && z < nz;
    }
    /// f(o, x, y, z) for cell c itself and each of its 26 neighbours in the frame (index, coordinates), z, y,
    /// x ascending: the step of the grids' propagations (SampleGrid's distance transform, NearestMap's fill).
    template <class F>
    void for_each_around(std::size_t c, F&& f) const {
        const Eigen::Array3i at = coordinates(c);
        for (int z = at.z() - 1; z <= at.z() + 1; ++z)
            for (int y = at.y() - 1; y <= at.y() + 1; ++y)
                for (int x = at.x() - 1; x <= at.x() + 1; ++x)
                    if (contains(x, y, z)) f(index(x, y, z), x, y, z);
    }
    /// The cell holding p, clamped into the frame: its coordinates, and its index.
    Eigen::Array3i clamped_cell(const Eigen::Vector3d& p) const;
    /// Whether the fields fit together as the constructor makes them (a frame read back from a file): a
    /// finite origin, a positive cell and its inverse, cells on every axis.
    bool consistent() const {
        return std::isfinite(origin.sum()) && cell > 0 && std::abs(inv_cell * cell - 1.0) <= 1e-12 &&
               nx > 0 && ny > 0 && nz > 0;
    }
    std::size_t clamped_index(const Eigen::Vector3d& p) const {
        const Eigen::Array3i c = clamped_cell(p);
        return index(c.x(), c.y(), c.z());
    }
};

/// Points sorted by the cell that holds them (clamped into the frame), CSR: the points of cell c are
/// order[start[c]], ..., order[start[c + 1] - 1], indices into the caller's array, in its order.
struct CellBuckets {
    std::vector<std::uint32_t> start, order;
};
CellBuckets bucket_by_cell(const CellFrame& frame, const std::vector<Eigen::Vector3d>& points);

/// Offers a sample at squared distance d2 to the k nearest found so far (`found` of them in indices and
/// squared_distances, nearest first; among equal distances the one offered first stays first). Returns
/// whether it was taken: the searches here (SampleGrid, Surface, NearestCache) all keep their answers so.
inline bool keep_nearest(int index, double d2, int k, int& found, int* indices, double* squared_distances) {
    if (found == k && d2 >= squared_distances[k - 1]) return false;
    int at = found < k ? found++ : k - 1;
    while (at > 0 && squared_distances[at - 1] > d2) {
        squared_distances[at] = squared_distances[at - 1];
        indices[at] = indices[at - 1];
        --at;
    }
    squared_distances[at] = d2;
    indices[at] = index;
    return true;
}

class SampleGrid {
  public:
    SampleGrid() = default;
    /// `spacing`: typical distance between neighbouring samples (sets the cell size; any positive value
    /// gives exact answers, a good one fast answers).
    SampleGrid(const std::vector<Eigen::Vector3d>& points, double spacing);
    /// A grid as built before over `points` (frame(), order(), starts() and distances() of it), e.g. read
    /// back from the model cache. Throws std::invalid_argument when the parts do not fit the points.
    SampleGrid(const std::vector<Eigen::Vector3d>& points, const CellFrame& frame,
               std::vector<std::uint32_t> order, std::vector<std::uint32_t> starts,
               std::vector<std::uint8_t> distances);

    static constexpr int kMaxK = 24;  ///< 20 for the statistical outlier filter (cloud_stats.hpp)

    /// The up to k (<= kMaxK) nearest samples within max_distance of p, nearest first: their indices and
    /// squared distances. Returns how many were found.
    int nearest(const Eigen::Vector3d& p, int k, double max_distance, int* indices,
                double* squared_distances) const;

    double cell_size() const { return frame_.cell; }
    bool empty() const { return points_.empty(); }
    const CellFrame& frame() const { return frame_; }
    /// The samples' indices in cell order; those of cell c are order()[starts()[c], starts()[c + 1]).
    const std::vector<std::uint32_t>& order() const { return index_; }
    const std::vector<std::uint32_t>& starts() const { return start_; }
    /// Per cell, the Chebyshev distance in cells to the nearest occupied one (at most 255).
    const std::vector<std::uint8_t>& distances() const { return distance_; }

  private:
    std::vector<Eigen::Vector3d>
        points_;                        // the samples in cell order (a copy: the grid can be copied freely)
    std::vector<std::uint32_t> index_;  // their indices in the caller's array
    CellFrame frame_;
    std::vector<std::uint32_t>
        start_;  // CSR over cells: samples of cell c are points_[start_[c], start_[c+1])
    std::vector<std::uint8_t>
        distance_;  // Chebyshev distance, in cells, to the nearest occupied cell (capped)
};

}  // namespace partloc
