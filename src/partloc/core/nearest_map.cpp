#include "partloc/core/nearest_map.hpp"

#include <Eigen/Geometry>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <utility>

namespace partloc {

NearestMap::NearestMap(const std::vector<Eigen::Vector3d>& points, double cell, double reach)
    : reach_(reach) {
    if (!(cell > 0) || !(reach >= 0))
        throw std::invalid_argument("NearestMap: cell must be > 0 and reach >= 0");
    if (points.empty()) return;
    Eigen::AlignedBox3d box;
    for (const auto& p : points) box.extend(p);
    box.min().array() -= reach;
    box.max().array() += reach;
    frame_ = CellFrame(box, cell, 16.0e6);
    const std::size_t n = frame_.count();
    nearest_.assign(n, -1);
    std::vector<float> d2(n, std::numeric_limits<float>::infinity());
    auto centre = [&](int x, int y, int z) {
        const Eigen::Vector3d& o = frame_.origin;
        const double h = frame_.cell;
        return Eigen::Vector3d(o.x() + h * (x + 0.5), o.y() + h * (y + 0.5), o.z() + h * (z + 0.5));
    };
    // Seeds: each sample in its own cell, the nearest to the centre winning.
    std::vector<std::size_t> front;
    for (std::size_t i = 0; i < points.size(); ++i) {
        const Eigen::Array3i at = frame_.clamped_cell(points[i]);  // inside: the box holds every sample
        const std::size_t c = frame_.index(at.x(), at.y(), at.z());
        const float d = static_cast<float>((points[i] - centre(at.x(), at.y(), at.z())).squaredNorm());
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
            const Eigen::Vector3d& s = points[nearest_[c]];
            frame_.for_each_around(c, [&](std::size_t o, int X, int Y, int Z) {
                if (nearest_[o] == nearest_[c]) return;
                const float d = static_cast<float>((s - centre(X, Y, Z)).squaredNorm());
                if (d >= d2[o] || d > reach2) return;
                d2[o] = d;
                nearest_[o] = nearest_[c];
                if (!queued[o]) {
                    queued[o] = 1;
                    next.push_back(o);
                }
            });
        }
        front.swap(next);
    }
}

NearestMap::NearestMap(const CellFrame& frame, double reach, std::vector<std::int32_t> cells,
                       std::size_t samples)
    : frame_(frame), reach_(reach), nearest_(std::move(cells)) {
    if (nearest_.empty()) return;  // a map of no samples
    if (!frame_.consistent() || !(reach_ >= 0) || nearest_.size() != frame_.count())
        throw std::invalid_argument("NearestMap: the cells do not fit the frame");
    for (const std::int32_t i : nearest_)
        if (i < -1 || (i >= 0 && static_cast<std::size_t>(i) >= samples))
            throw std::invalid_argument("NearestMap: a cell names a sample that is not there");
}

int NearestMap::nearest(const Eigen::Vector3d& p) const {
    if (nearest_.empty()) return -1;
    const Eigen::Vector3d f = (p - frame_.origin) * frame_.inv_cell;
    const CellFrame& g = frame_;
    if (!(f.x() >= 0 && f.y() >= 0 && f.z() >= 0 && f.x() < g.nx && f.y() < g.ny && f.z() < g.nz)) return -1;
    return nearest_[g.index(static_cast<int>(f.x()), static_cast<int>(f.y()), static_cast<int>(f.z()))];
}

}  // namespace partloc
