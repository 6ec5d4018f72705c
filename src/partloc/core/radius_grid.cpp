#include "partloc/core/radius_grid.hpp"

#include "partloc/core/sample_grid.hpp"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace partloc {

RadiusGrid::RadiusGrid(const std::vector<Eigen::Vector3d>& points, double cell) {
    if (!(cell > 0)) throw std::invalid_argument("RadiusGrid: cell must be > 0");
    if (points.empty()) return;
    Eigen::AlignedBox3d box;
    for (const auto& p : points) box.extend(p);
    const CellFrame frame(box, cell, 2.0e6);
    cell_ = frame.cell;
    origin_ = frame.origin;
    nx_ = frame.nx;
    ny_ = frame.ny;
    nz_ = frame.nz;
    auto cell_of = [&](const Eigen::Vector3d& p) { return frame.clamped_index(p); };
    start_.assign(frame.count() + 1, 0);
    std::vector<std::uint32_t> of(points.size());
    for (std::size_t i = 0; i < points.size(); ++i) {
        of[i] = static_cast<std::uint32_t>(cell_of(points[i]));
        ++start_[of[i] + 1];
    }
    for (std::size_t c = 1; c < start_.size(); ++c) start_[c] += start_[c - 1];
    points_.resize(points.size());
    index_.resize(points.size());
    std::vector<std::uint32_t> fill(start_.begin(), start_.end() - 1);
    for (std::size_t i = 0; i < points.size(); ++i) {
        const std::uint32_t at = fill[of[i]]++;
        points_[at] = points[i];
        index_[at] = static_cast<std::uint32_t>(i);
    }
}

void RadiusGrid::within(const Eigen::Vector3d& centre, double radius, std::vector<int>& out) const {
    out.clear();
    if (points_.empty() || !(radius > 0)) return;
    const double r2 = radius * radius;
    const Eigen::Vector3d lo = (centre.array() - radius - origin_.array()) / cell_;
    const Eigen::Vector3d hi = (centre.array() + radius - origin_.array()) / cell_;
    if (hi.x() < 0 || hi.y() < 0 || hi.z() < 0 || lo.x() >= nx_ || lo.y() >= ny_ || lo.z() >= nz_) return;
    const int x0 = std::max(0, static_cast<int>(std::floor(lo.x()))), x1 = std::min(nx_ - 1, static_cast<int>(hi.x()));
    const int y0 = std::max(0, static_cast<int>(std::floor(lo.y()))), y1 = std::min(ny_ - 1, static_cast<int>(hi.y()));
    const int z0 = std::max(0, static_cast<int>(std::floor(lo.z()))), z1 = std::min(nz_ - 1, static_cast<int>(hi.z()));
    // Squared distance from the centre to the nearest and the farthest point of a cell's span on one axis.
    auto span = [&](double c, int i, double o, double* near2, double* far2) {
        const double a = o + i * cell_, b = a + cell_;
        const double dn = c < a ? a - c : (c > b ? c - b : 0.0);
        const double df = std::max(std::abs(c - a), std::abs(c - b));
        *near2 = dn * dn;
        *far2 = df * df;
    };
    for (int z = z0; z <= z1; ++z) {
        double nz2, fz2;
        span(centre.z(), z, origin_.z(), &nz2, &fz2);
        if (nz2 >= r2) continue;
        for (int y = y0; y <= y1; ++y) {
            double ny2, fy2;
            span(centre.y(), y, origin_.y(), &ny2, &fy2);
            if (nz2 + ny2 >= r2) continue;
            for (int x = x0; x <= x1; ++x) {
                double nx2, fx2;
                span(centre.x(), x, origin_.x(), &nx2, &fx2);
                if (nz2 + ny2 + nx2 >= r2) continue;
                const std::size_t c = (static_cast<std::size_t>(z) * ny_ + y) * nx_ + x;
                const std::uint32_t a = start_[c], b = start_[c + 1];
                if (a == b) continue;
                // A cell wholly inside the ball needs no test (with a margin for rounding: the test decides
                // points near the sphere).
                const bool inside = fz2 + fy2 + fx2 < r2 * (1.0 - 1e-9);
                for (std::uint32_t j = a; j < b; ++j)
                    if (inside || (points_[j] - centre).squaredNorm() < r2) out.push_back(static_cast<int>(index_[j]));
            }
        }
    }
    std::sort(out.begin(), out.end());
}

}  // namespace partloc
