#include "partloc/core/radius_grid.hpp"

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
    frame_ = CellFrame(box, cell, 2.0e6);
    CellBuckets b = bucket_by_cell(frame_, points);
    start_ = std::move(b.start);
    index_ = std::move(b.order);
    points_.resize(points.size());
    for (std::size_t j = 0; j < index_.size(); ++j) points_[j] = points[index_[j]];
}

namespace {

// Distinct indices below n, in ascending order. Thousands of them (the points around a fiducial: tens of
// thousands of a scan's hundreds of thousands) by a bitmap over all n, which takes n / 64 words; fewer by a
// sort. The same order as std::sort gives.
void ascending(std::vector<int>& idx, std::size_t n) {
    if (idx.size() < 1024 || idx.size() * 16 < n / 64) {
        std::sort(idx.begin(), idx.end());
        return;
    }
    thread_local std::vector<std::uint64_t> bits;
    bits.assign(n / 64 + 1, 0);
    for (const int i : idx) bits[static_cast<std::size_t>(i) >> 6] |= std::uint64_t(1) << (i & 63);
    idx.clear();
    for (std::size_t w = 0; w < bits.size(); ++w)
        for (std::uint64_t b = bits[w]; b != 0; b &= b - 1)
            idx.push_back(static_cast<int>(w * 64 + static_cast<std::size_t>(__builtin_ctzll(b))));
}

}  // namespace

void RadiusGrid::within(const Eigen::Vector3d& centre, double radius, std::vector<int>& out,
                        bool sorted) const {
    out.clear();
    if (points_.empty() || !(radius > 0)) return;
    const double r2 = radius * radius;
    const Eigen::Vector3d lo = (centre.array() - radius - frame_.origin.array()) / frame_.cell;
    const Eigen::Vector3d hi = (centre.array() + radius - frame_.origin.array()) / frame_.cell;
    if (hi.x() < 0 || hi.y() < 0 || hi.z() < 0 || lo.x() >= frame_.nx || lo.y() >= frame_.ny ||
        lo.z() >= frame_.nz)
        return;
    // The bounds clamped as doubles before the cast (a ball far outside the grid overflowed int, undefined):
    // the same cells as before for every ball, and an empty range for one that misses the grid or is NaN.
    const auto first = [](double v, int n) {
        if (v >= 0) return static_cast<int>(std::min(std::floor(v), double(n)));
        return v < 0 ? 0 : n;
    };
    const auto last = [](double v, int n) { return v >= -1 ? static_cast<int>(std::min(v, n - 1.0)) : -1; };
    const int x0 = first(lo.x(), frame_.nx), x1 = last(hi.x(), frame_.nx);
    const int y0 = first(lo.y(), frame_.ny), y1 = last(hi.y(), frame_.ny);
    const int z0 = first(lo.z(), frame_.nz), z1 = last(hi.z(), frame_.nz);
    if (x1 - x0 <= 2 && y1 - y0 <= 2 && z1 - z0 <= 2) {
        // A small ball (the normals' neighbours, a ball of a cell's radius): every point of the rows of its
        // at most 27 cells is tested, row by row (a row's cells are consecutive in the CSR arrays). The same
        // points in the same order as the walk below, which spends more on its cells than on their points
        // here.
        for (int z = z0; z <= z1; ++z)
            for (int y = y0; y <= y1; ++y)
                for (std::uint32_t j = start_[frame_.index(x0, y, z)], e = start_[frame_.index(x1, y, z) + 1];
                     j < e; ++j)
                    if ((points_[j] - centre).squaredNorm() < r2) out.push_back(static_cast<int>(index_[j]));
        if (sorted) ascending(out, points_.size());
        return;
    }
    // Squared distance from the centre to the nearest and the farthest point of a cell's span on one axis.
    auto span = [&](double c, int i, double o, double* near2, double* far2) {
        const double a = o + i * frame_.cell, b = a + frame_.cell;
        const double dn = c < a ? a - c : (c > b ? c - b : 0.0);
        const double df = std::max(std::abs(c - a), std::abs(c - b));
        *near2 = dn * dn;
        *far2 = df * df;
    };
    for (int z = z0; z <= z1; ++z) {
        double nz2, fz2;
        span(centre.z(), z, frame_.origin.z(), &nz2, &fz2);
        if (nz2 >= r2) continue;
        for (int y = y0; y <= y1; ++y) {
            double ny2, fy2;
            span(centre.y(), y, frame_.origin.y(), &ny2, &fy2);
            if (nz2 + ny2 >= r2) continue;
            for (int x = x0; x <= x1; ++x) {
                double nx2, fx2;
                span(centre.x(), x, frame_.origin.x(), &nx2, &fx2);
                if (nz2 + ny2 + nx2 >= r2) continue;
                const std::size_t c = frame_.index(x, y, z);
                const std::uint32_t a = start_[c], b = start_[c + 1];
                if (a == b) continue;
                // A cell wholly inside the ball needs no test (with a margin for rounding: the test decides
                // points near the sphere).
                const bool inside = fz2 + fy2 + fx2 < r2 * (1.0 - 1e-9);
                for (std::uint32_t j = a; j < b; ++j)
                    if (inside || (points_[j] - centre).squaredNorm() < r2)
                        out.push_back(static_cast<int>(index_[j]));
            }
        }
    }
    if (sorted) ascending(out, points_.size());
}

}  // namespace partloc
