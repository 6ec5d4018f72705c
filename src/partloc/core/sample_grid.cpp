#include "partloc/core/sample_grid.hpp"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <deque>
#include <limits>
#include <stdexcept>

namespace partloc {

CellFrame::CellFrame(const Eigen::AlignedBox3d& box, double c, double max_cells) : origin(box.min()), cell(c) {
    const Eigen::Vector3d size = box.sizes();
    auto cells = [&](double k) {
        return (std::floor(size.x() / k) + 1) * (std::floor(size.y() / k) + 1) * (std::floor(size.z() / k) + 1);
    };
    while (cells(cell) > max_cells) cell *= 1.25;
    nx = static_cast<int>(std::floor(size.x() / cell)) + 1;
    ny = static_cast<int>(std::floor(size.y() / cell)) + 1;
    nz = static_cast<int>(std::floor(size.z() / cell)) + 1;
}

Eigen::Array3i CellFrame::clamped_cell(const Eigen::Vector3d& p) const {
    const Eigen::Vector3d f = (p - origin) / cell;
    return {std::clamp(static_cast<int>(f.x()), 0, nx - 1), std::clamp(static_cast<int>(f.y()), 0, ny - 1),
            std::clamp(static_cast<int>(f.z()), 0, nz - 1)};
}

SampleGrid::SampleGrid(const std::vector<Eigen::Vector3d>& points, double spacing) {
    if (points.empty()) return;
    if (!(spacing > 0)) throw std::invalid_argument("SampleGrid: spacing must be > 0");
    Eigen::AlignedBox3d box;
    for (const auto& p : points) box.extend(p);
    // Cells of 1.5 spacings hold the 4-8 nearest samples of a point on the surface within the 27 around it;
    // a very large bounding box gets larger cells to keep the grid within 8 million cells.
    const CellFrame frame(box, 1.5 * spacing, 8.0e6);
    cell_ = frame.cell;
    inv_cell_ = 1.0 / cell_;
    origin_ = frame.origin;
    nx_ = frame.nx;
    ny_ = frame.ny;
    nz_ = frame.nz;
    const std::size_t n = frame.count();
    auto cell_of = [&](const Eigen::Vector3d& p) { return frame.clamped_index(p); };
    start_.assign(n + 1, 0);
    std::vector<std::size_t> cell(points.size());
    for (std::size_t i = 0; i < points.size(); ++i) {
        cell[i] = cell_of(points[i]);
        ++start_[cell[i] + 1];
    }
    for (std::size_t c = 0; c < n; ++c) start_[c + 1] += start_[c];
    points_.resize(points.size());
    index_.resize(points.size());
    std::vector<std::uint32_t> fill(start_.begin(), start_.end() - 1);
    for (std::size_t i = 0; i < points.size(); ++i) {
        const std::uint32_t at = fill[cell[i]]++;
        points_[at] = points[i];
        index_[at] = static_cast<std::uint32_t>(i);
    }
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
        const int x = static_cast<int>(c % nx_), y = static_cast<int>((c / nx_) % ny_),
                  z = static_cast<int>(c / (static_cast<std::size_t>(nx_) * ny_));
        for (int dz = -1; dz <= 1; ++dz)
            for (int dy = -1; dy <= 1; ++dy)
                for (int dx = -1; dx <= 1; ++dx) {
                    const int X = x + dx, Y = y + dy, Z = z + dz;
                    if (X < 0 || Y < 0 || Z < 0 || X >= nx_ || Y >= ny_ || Z >= nz_) continue;
                    const std::size_t o = (static_cast<std::size_t>(Z) * ny_ + Y) * nx_ + X;
                    if (distance_[o] <= d + 1) continue;
                    distance_[o] = static_cast<std::uint8_t>(d + 1);
                    queue.push_back(o);
                }
    }
}

int SampleGrid::nearest(const Eigen::Vector3d& p, int k, double max_distance, int* indices,
                        double* squared_distances) const {
    if (points_.empty() || k <= 0) return 0;
    k = std::min(k, kMaxK);
    const double max_d2 = max_distance * max_distance;
    const Eigen::Vector3d f = (p - origin_) * inv_cell_;
    // The point's cell, which may lie outside the grid; cells outside hold no samples.
    const double fx = std::floor(f.x()), fy = std::floor(f.y()), fz = std::floor(f.z());
    const double big = 1e9;
    if (std::abs(fx) > big || std::abs(fy) > big || std::abs(fz) > big) return 0;
    const int ix = static_cast<int>(fx), iy = static_cast<int>(fy), iz = static_cast<int>(fz);
    // A sample in a cell r cells away (Chebyshev) is at least (r - 1) cells away in space.
    const int out = std::max({0, -ix, ix - (nx_ - 1), -iy, iy - (ny_ - 1), -iz, iz - (nz_ - 1)});
    int first = out;
    if (out == 0) {
        first = distance_[(static_cast<std::size_t>(iz) * ny_ + iy) * nx_ + ix];  // 255: at least that
    }
    if ((first - 1) * cell_ > max_distance) return 0;
    // Best k so far, nearest first (insertion into a short sorted array).
    int found = 0;
    auto consider = [&](std::uint32_t a, std::uint32_t b) {
        for (std::uint32_t j = a; j < b; ++j) {
            const double d2 = (points_[j] - p).squaredNorm();
            if (d2 > max_d2 || (found == k && d2 >= squared_distances[k - 1])) continue;
            int at = found < k ? found++ : k - 1;
            while (at > 0 && squared_distances[at - 1] > d2) {
                squared_distances[at] = squared_distances[at - 1];
                indices[at] = indices[at - 1];
                --at;
            }
            squared_distances[at] = d2;
            indices[at] = static_cast<int>(index_[j]);
        }
    };
    auto visit = [&](int x, int y, int z) {
        if (x < 0 || y < 0 || z < 0 || x >= nx_ || y >= ny_ || z >= nz_) return;
        const std::size_t c = (static_cast<std::size_t>(z) * ny_ + y) * nx_ + x;
        consider(start_[c], start_[c + 1]);
    };
    const int max_r = out + std::max(nx_, std::max(ny_, nz_));
    for (int r = std::max(0, first - 1); r <= max_r; ++r) {
        if ((r - 1) * cell_ > max_distance) break;  // every sample in this shell is beyond the bound
        // The shell of cells at Chebyshev distance r, clipped to the grid.
        const int z0 = std::max(iz - r, 0), z1 = std::min(iz + r, nz_ - 1);
        const int y0 = std::max(iy - r, 0), y1 = std::min(iy + r, ny_ - 1);
        for (int z = z0; z <= z1; ++z)
            for (int y = y0; y <= y1; ++y) {
                if (r == 0 || std::abs(z - iz) == r || std::abs(y - iy) == r) {
                    const int x0 = std::max(ix - r, 0), x1 = std::min(ix + r, nx_ - 1);
                    for (int x = x0; x <= x1; ++x) visit(x, y, z);
                } else {
                    visit(ix - r, y, z);
                    visit(ix + r, y, z);
                }
            }
        // Every sample not yet seen lies at least r cells (in space) from p.
        if (found == k && squared_distances[k - 1] <= (r * cell_) * (r * cell_)) break;
    }
    return found;
}

}  // namespace partloc
