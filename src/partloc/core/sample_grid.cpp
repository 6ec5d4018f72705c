#include "partloc/core/sample_grid.hpp"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <deque>
#include <limits>
#include <numeric>
#include <stdexcept>
#include <utility>

namespace partloc {

CellFrame::CellFrame(const Eigen::AlignedBox3d& box, double c, double max_cells)
    : origin(box.min()), cell(c) {
    const Eigen::Vector3d size = box.sizes();
    auto cells = [&](double k) {
        return (std::floor(size.x() / k) + 1) * (std::floor(size.y() / k) + 1) *
               (std::floor(size.z() / k) + 1);
    };
    while (cells(cell) > max_cells) cell *= 1.25;
    inv_cell = 1.0 / cell;
    nx = static_cast<int>(std::floor(size.x() / cell)) + 1;
    ny = static_cast<int>(std::floor(size.y() / cell)) + 1;
    nz = static_cast<int>(std::floor(size.z() / cell)) + 1;
}

Eigen::Array3i CellFrame::clamped_cell(const Eigen::Vector3d& p) const {
    const Eigen::Vector3d f = (p - origin) * inv_cell;
    // Clamped as doubles, then cast: a point far outside the frame (1e9 cells away) cast first overflowed int
    // (undefined; clang's float-cast-overflow check). The same cells for every point that fits; NaN gives 0.
    const auto clamped = [](double v, int n) { return v >= 0 ? static_cast<int>(std::min(v, n - 1.0)) : 0; };
    return {clamped(f.x(), nx), clamped(f.y(), ny), clamped(f.z(), nz)};
}

CellBuckets bucket_by_cell(const CellFrame& frame, const std::vector<Eigen::Vector3d>& points) {
    CellBuckets b;
    b.start.assign(frame.count() + 1, 0);
    std::vector<std::uint32_t> cell(points.size());
    for (std::size_t i = 0; i < points.size(); ++i) {
        cell[i] = static_cast<std::uint32_t>(frame.clamped_index(points[i]));
        ++b.start[cell[i] + 1];
    }
    std::partial_sum(b.start.begin(), b.start.end(), b.start.begin());
    b.order.resize(points.size());
    std::vector<std::uint32_t> fill(b.start.begin(), b.start.end() - 1);
    for (std::size_t i = 0; i < points.size(); ++i) b.order[fill[cell[i]]++] = static_cast<std::uint32_t>(i);
    return b;
}

SampleGrid::SampleGrid(const std::vector<Eigen::Vector3d>& points, double spacing) {
    if (points.empty()) return;
    if (!(spacing > 0)) throw std::invalid_argument("SampleGrid: spacing must be > 0");
    Eigen::AlignedBox3d box;
    for (const auto& p : points) box.extend(p);
    // Cells of 1.5 spacings hold the 4-8 nearest samples of a point on the surface within the 27 around it;
    // a very large bounding box gets larger cells to keep the grid within 8 million cells.
    frame_ = CellFrame(box, 1.5 * spacing, 8.0e6);
    const std::size_t n = frame_.count();
    CellBuckets b = bucket_by_cell(frame_, points);
    start_ = std::move(b.start);
    index_ = std::move(b.order);
    points_.resize(points.size());
    for (std::size_t j = 0; j < index_.size(); ++j) points_[j] = points[index_[j]];
    // Chebyshev distance transform of the occupied cells by breadth-first search over 26-neighbours.
    distance_.assign(n, 255);
    std::deque<std::size_t> queue;
    for (std::size_t c = 0; c < n; ++c)
        if (start_[c + 1] > start_[c]) {
            distance_[c] = 0;
            queue.push_back(c);
        }
    while (!queue.empty()) {
        const std::size_t c = queue.front();
        queue.pop_front();
        const int d = distance_[c];
        if (d >= 254) continue;
        frame_.for_each_around(c, [&](std::size_t o, int, int, int) {
            if (distance_[o] <= d + 1) return;
            distance_[o] = static_cast<std::uint8_t>(d + 1);
            queue.push_back(o);
        });
    }
}

SampleGrid::SampleGrid(const std::vector<Eigen::Vector3d>& points, const CellFrame& frame,
                       std::vector<std::uint32_t> order, std::vector<std::uint32_t> starts,
                       std::vector<std::uint8_t> distances)
    : index_(std::move(order)), frame_(frame), start_(std::move(starts)), distance_(std::move(distances)) {
    if (points.empty() && index_.empty() && start_.empty() && distance_.empty()) return;  // an empty grid
    const std::size_t n = frame_.count();
    if (!frame_.consistent() || start_.size() != n + 1 || distance_.size() != n ||
        index_.size() != points.size() || start_.front() != 0 || start_.back() != points.size())
        throw std::invalid_argument("SampleGrid: the cells do not fit the points");
    for (std::size_t c = 0; c < n; ++c)
        if (start_[c + 1] < start_[c]) throw std::invalid_argument("SampleGrid: the cells' starts decrease");
    points_.resize(points.size());
    for (std::size_t j = 0; j < index_.size(); ++j) {
        if (index_[j] >= points.size()) throw std::invalid_argument("SampleGrid: a cell names no sample");
        points_[j] = points[index_[j]];
    }
}

int SampleGrid::nearest(const Eigen::Vector3d& p, int k, double max_distance, int* indices,
                        double* squared_distances) const {
    if (points_.empty() || k <= 0) return 0;
    k = std::min(k, kMaxK);
    const double max_d2 = max_distance * max_distance;
    const Eigen::Vector3d f = (p - frame_.origin) * frame_.inv_cell;
    // The point's cell, which may lie outside the grid; cells outside hold no samples.
    const double fx = std::floor(f.x()), fy = std::floor(f.y()), fz = std::floor(f.z());
    const double big = 1e9;
    if (std::abs(fx) > big || std::abs(fy) > big || std::abs(fz) > big) return 0;
    const int ix = static_cast<int>(fx), iy = static_cast<int>(fy), iz = static_cast<int>(fz);
    // A sample in a cell r cells away (Chebyshev) is at least (r - 1) cells away in space.
    const int out =
        std::max({0, -ix, ix - (frame_.nx - 1), -iy, iy - (frame_.ny - 1), -iz, iz - (frame_.nz - 1)});
    int first = out;
    if (out == 0) {
        first = distance_[frame_.index(ix, iy, iz)];  // 255: at least that
    }
    if ((first - 1) * frame_.cell > max_distance) return 0;
    // Best k so far, nearest first (insertion into a short sorted array).
    int found = 0;
    auto consider = [&](std::uint32_t a, std::uint32_t b) {
        for (std::uint32_t j = a; j < b; ++j) {
            const double d2 = (points_[j] - p).squaredNorm();
            if (d2 <= max_d2)
                keep_nearest(static_cast<int>(index_[j]), d2, k, found, indices, squared_distances);
        }
    };
    auto visit = [&](int x, int y, int z) {
        if (!frame_.contains(x, y, z)) return;
        const std::size_t c = frame_.index(x, y, z);
        consider(start_[c], start_[c + 1]);
    };
    // Every sample outside the cells within Chebyshev distance r of p's cell lies at least this far from p:
    // r cells, and p's distance to the nearest face of its own cell (not only r cells: half the queries
    // near a surface then stop at the 27 cells around p instead of searching the next shell).
    const double margin = std::min(
        {f.x() - fx, 1.0 - (f.x() - fx), f.y() - fy, 1.0 - (f.y() - fy), f.z() - fz, 1.0 - (f.z() - fz)});
    const auto reached = [&](int r) { return (r + std::max(0.0, margin)) * frame_.cell; };
    // Cells closer (Chebyshev) to p's cell than `first` hold no sample: the distance transform, or the grid's
    // outside.
    int r_first = first;
    if (r_first <= 1 && ix >= 1 && iy >= 1 && iz >= 1 && ix + 1 < frame_.nx && iy + 1 < frame_.ny &&
        iz + 1 < frame_.nz) {
        // The usual query, near the surface and inside the grid: the 27 cells around p at once. Three cells
        // along x are consecutive in the CSR arrays, so the block is nine runs of samples.
        for (int z = iz - 1; z <= iz + 1; ++z)
            for (int y = iy - 1; y <= iy + 1; ++y) {
                const std::size_t c = frame_.index(ix - 1, y, z);
                consider(start_[c], start_[c + 3]);
            }
        if (found == k && squared_distances[k - 1] <= reached(1) * reached(1)) return found;
        r_first = 2;
    }
    const int max_r = out + std::max(frame_.nx, std::max(frame_.ny, frame_.nz));
    for (int r = r_first; r <= max_r; ++r) {
        if (r > 0 && reached(r - 1) > max_distance) break;  // every sample in this shell is beyond the bound
        // The shell of cells at Chebyshev distance r, clipped to the grid.
        const int z0 = std::max(iz - r, 0), z1 = std::min(iz + r, frame_.nz - 1);
        const int y0 = std::max(iy - r, 0), y1 = std::min(iy + r, frame_.ny - 1);
        for (int z = z0; z <= z1; ++z)
            for (int y = y0; y <= y1; ++y) {
                if (r == 0 || std::abs(z - iz) == r || std::abs(y - iy) == r) {
                    // A whole row of the shell: its cells are consecutive in the CSR arrays.
                    const int x0 = std::max(ix - r, 0), x1 = std::min(ix + r, frame_.nx - 1);
                    if (x0 <= x1)
                        consider(start_[frame_.index(x0, y, z)], start_[frame_.index(x1, y, z) + 1]);
                } else {
                    visit(ix - r, y, z);
                    visit(ix + r, y, z);
                }
            }
        // Every sample not yet seen lies at least r cells (in space) from p.
        if (found == k && squared_distances[k - 1] <= reached(r) * reached(r)) break;
    }
    return found;
}

}  // namespace partloc
