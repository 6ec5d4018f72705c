#include "partloc/core/nearest_map.hpp"

#include "partloc/core/sample_grid.hpp"

#include <Eigen/Geometry>
#include <cmath>
#include <limits>
#include <stdexcept>

namespace partloc {

NearestMap::NearestMap(const std::vector<Eigen::Vector3d>& points, double cell, double reach)
    : reach_(reach) {
    if (!(cell > 0) || !(reach >= 0)) throw std::invalid_argument("NearestMap: cell must be > 0 and reach >= 0");
    if (points.empty()) return;
    Eigen::AlignedBox3d box;
    for (const auto& p : points) box.extend(p);
    box.min().array() -= reach;
    box.max().array() += reach;
    const CellFrame frame(box, cell, 16.0e6);
    cell_ = frame.cell;
    inv_cell_ = 1.0 / cell_;
    origin_ = frame.origin;
    nx_ = frame.nx;
    ny_ = frame.ny;
    nz_ = frame.nz;
    const std::size_t n = frame.count();
    nearest_.assign(n, -1);
    std::vector<float> d2(n, std::numeric_limits<float>::infinity());
    auto centre = [&](int x, int y, int z) {
        return Eigen::Vector3d(origin_.x() + cell_ * (x + 0.5), origin_.y() + cell_ * (y + 0.5),
                               origin_.z() + cell_ * (z + 0.5));
    };
    // Seeds: each sample in its own cell, the nearest to the centre winning.
    std::vector<std::size_t> front;
    for (std::size_t i = 0; i < points.size(); ++i) {
        const Eigen::Vector3d f = (points[i] - origin_) * inv_cell_;
        const int x = static_cast<int>(f.x()), y = static_cast<int>(f.y()), z = static_cast<int>(f.z());
        const std::size_t c = (static_cast<std::size_t>(z) * ny_ + y) * nx_ + x;
        const float d = static_cast<float>((points[i] - centre(x, y, z)).squaredNorm());
        if (nearest_[c] < 0) front.push_back(c);
        if (d < d2[c]) {
            d2[c] = d;
            nearest_[c] = static_cast<std::int32_t>(i);
        }
    }
    // Spread, layer by layer, to the 26 neighbours while that brings a cell a nearer sample within reach.
    const float reach2 = static_cast<float>(reach * reach);
    std::vector<char> queued(n, 0);
    std::vector<std::size_t> next;
    while (!front.empty()) {
        next.clear();
        for (const std::size_t c : front) {
            queued[c] = 0;
            const int x = static_cast<int>(c % nx_), y = static_cast<int>((c / nx_) % ny_),
                      z = static_cast<int>(c / (static_cast<std::size_t>(nx_) * ny_));
            const Eigen::Vector3d& s = points[nearest_[c]];
            for (int dz = -1; dz <= 1; ++dz)
                for (int dy = -1; dy <= 1; ++dy)
                    for (int dx = -1; dx <= 1; ++dx) {
                        const int X = x + dx, Y = y + dy, Z = z + dz;
                        if (X < 0 || Y < 0 || Z < 0 || X >= nx_ || Y >= ny_ || Z >= nz_) continue;
                        const std::size_t o = (static_cast<std::size_t>(Z) * ny_ + Y) * nx_ + X;
                        if (nearest_[o] == nearest_[c]) continue;
                        const float d = static_cast<float>((s - centre(X, Y, Z)).squaredNorm());
                        if (d >= d2[o] || d > reach2) continue;
                        d2[o] = d;
                        nearest_[o] = nearest_[c];
                        if (!queued[o]) {
                            queued[o] = 1;
                            next.push_back(o);
                        }
                    }
        }
        front.swap(next);
    }
}

int NearestMap::nearest(const Eigen::Vector3d& p) const {
    if (nearest_.empty()) return -1;
    const Eigen::Vector3d f = (p - origin_) * inv_cell_;
    if (!(f.x() >= 0 && f.y() >= 0 && f.z() >= 0 && f.x() < nx_ && f.y() < ny_ && f.z() < nz_)) return -1;
    const int x = static_cast<int>(f.x()), y = static_cast<int>(f.y()), z = static_cast<int>(f.z());
    return nearest_[(static_cast<std::size_t>(z) * ny_ + y) * nx_ + x];
}

}  // namespace partloc
