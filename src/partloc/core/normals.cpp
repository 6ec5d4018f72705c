#include "partloc/core/normals.hpp"

#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <stdexcept>
#include <utility>

#include "partloc/core/cell_key.hpp"
#include "partloc/core/radius_grid.hpp"

namespace partloc {

Eigen::Vector3d pca_normal(const std::vector<Eigen::Vector3d>& pts, const std::vector<int>& idx) {
    if (idx.size() < 3) return Eigen::Vector3d::Zero();
    Eigen::Vector3d mean = Eigen::Vector3d::Zero();
    for (int j : idx) mean += pts[j];
    mean /= static_cast<double>(idx.size());
    Eigen::Matrix3d C = Eigen::Matrix3d::Zero();
    for (int j : idx) {
        const Eigen::Vector3d d = pts[j] - mean;
        C.noalias() += d * d.transpose();
    }
    if (!(C.trace() > 0)) return Eigen::Vector3d::Zero();
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es;
    es.computeDirect(C);
    return es.eigenvectors().col(0).normalized();
}

RadiusGrid normals_grid(const std::vector<Eigen::Vector3d>& points, double radius) {
    // Cells of the radius: a ball then spans at most three cells on each axis, and RadiusGrid::within tests
    // every point of their nine rows. Seed 106's 298 k queries took 105-135 ms (timed inside within, both
    // threads summed) against 240-255 ms in cells of half the radius, where the walk over 125 cells costs
    // more than their points; 1.25 radius took 110 ms, 0.75 radius 212 ms.
    return radius > 0 ? RadiusGrid(points, radius) : RadiusGrid();
}

std::vector<Eigen::Vector3d> estimate_normals(const std::vector<Eigen::Vector3d>& points, double radius,
                                              int max_nn, const std::vector<std::size_t>* at) {
    if (points.size() < 3 || !(radius > 0) || max_nn < 3)
        return std::vector<Eigen::Vector3d>(at ? at->size() : points.size(), Eigen::Vector3d::UnitZ());
    return estimate_normals(points, normals_grid(points, radius), radius, max_nn, at);
}

std::vector<Eigen::Vector3d> estimate_normals(const std::vector<Eigen::Vector3d>& points,
                                              const RadiusGrid& grid, double radius, int max_nn,
                                              const std::vector<std::size_t>* at) {
    const std::size_t n = at ? at->size() : points.size();
    std::vector<Eigen::Vector3d> out(n, Eigen::Vector3d::UnitZ());
    if (points.size() < 3 || !(radius > 0) || max_nn < 3) return out;
    if (grid.size() != points.size())
        throw std::invalid_argument("estimate_normals: the grid is not the points'");
    struct Buffers {
        std::vector<int> idx;
        std::vector<std::pair<double, int>> by_distance;
    };
    tbb::enumerable_thread_specific<Buffers> buffers;
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 256),
                      [&](const tbb::blocked_range<std::size_t>& range) {
                          Buffers& b = buffers.local();
                          for (std::size_t i = range.begin(); i != range.end(); ++i) {
                              const Eigen::Vector3d& p = points[at ? (*at)[i] : i];
                              grid.within(p, radius, b.idx, false);
                              if (b.idx.size() > static_cast<std::size_t>(max_nn)) {
                                  // The max_nn nearest; which of several at the same distance is taken does
                                  // not matter here.
                                  b.by_distance.clear();
                                  for (int j : b.idx)
                                      b.by_distance.emplace_back((points[j] - p).squaredNorm(), j);
                                  std::nth_element(b.by_distance.begin(),
                                                   b.by_distance.begin() + (max_nn - 1), b.by_distance.end());
                                  b.idx.resize(max_nn);
                                  for (int k = 0; k < max_nn; ++k) b.idx[k] = b.by_distance[k].second;
                              }
                              // The sum below in a fixed order, whatever order nth_element or the grid's
                              // cells left.
                              std::sort(b.idx.begin(), b.idx.end());
                              const Eigen::Vector3d normal = pca_normal(points, b.idx);
                              if (normal.squaredNorm() > 0) out[i] = normal;
                          }
                      });
    return out;
}

OrientedSample voxel_normals(const std::vector<Eigen::Vector3d>& points, double cell,
                             const Eigen::Vector3d& viewpoint) {
    // Sums per cube of half the cell; a normal from the 4 x 4 x 4 of them around its cell: a cube of twice
    // the cell. With the 27 cells around (three times the cell), seed 11's test cell lost two scans that see
    // fiducial A well (no fiducial fits), and seeds 2200-2299 registered 571
    // scans right; with twice the cell 585 (569 with the normals of each point of a grid of half the cell,
    // from its neighbours within 1.5 cells, averaged per cell, as before).
    constexpr int sub = 2, margin = 1;
    OrientedSample out;
    if (points.empty() || !(cell > 0)) return out;
    Eigen::AlignedBox3d box;
    for (const auto& p : points) box.extend(p);
    cells::Lattice lattice;  // the cubes of the sums
    lattice.edge = std::max(
        cell / sub, box.diagonal().maxCoeff() / static_cast<double>(cells::kMask - 4 * sub - 4 * margin));
    lattice.origin = box.min() - Eigen::Vector3d::Constant((sub + margin) * lattice.edge);  // keys stay >= 0
    // Per cube: count, sum and sum of outer products, about the lattice's origin (coordinates of at most a
    // few metres: the covariance keeps ten significant digits).
    struct Sums {
        double n = 0;
        Eigen::Vector3d s = Eigen::Vector3d::Zero();
        Eigen::Matrix3d ss = Eigen::Matrix3d::Zero();
    };
    std::vector<Sums> sums;
    cells::KeyIndex index;
    // The output's cells (sub^3 cubes each): count and sum, in the order the points first reach them.
    std::vector<Eigen::Array3i> coarse;
    std::vector<std::pair<double, Eigen::Vector3d>> mean;
    cells::KeyIndex coarse_index;
    for (const auto& p : points) {
        const Eigen::Array3i f = lattice.cell_of(p);
        const std::uint32_t c = index.find_or_add(cells::pack(f), static_cast<std::uint32_t>(sums.size()));
        if (c == sums.size()) sums.emplace_back();
        const Eigen::Vector3d q = p - lattice.origin;
        Sums& m = sums[c];
        m.n += 1;
        m.s += q;
        m.ss.noalias() += q * q.transpose();
        const Eigen::Array3i g = f / sub;  // f >= 0
        const std::uint32_t o =
            coarse_index.find_or_add(cells::pack(g), static_cast<std::uint32_t>(coarse.size()));
        if (o == coarse.size()) {
            coarse.push_back(g);
            mean.emplace_back(0.0, Eigen::Vector3d::Zero());
        }
        mean[o].first += 1;
        mean[o].second += q;
    }
    out.points.resize(coarse.size());
    out.normals.resize(coarse.size());
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, coarse.size(), 512), [&](const auto& range) {
        for (std::size_t c = range.begin(); c != range.end(); ++c) {
            out.points[c] = lattice.origin + mean[c].second / mean[c].first;
            const Eigen::Array3i lo = coarse[c] * sub - margin, hi = coarse[c] * sub + (sub - 1 + margin);
            Sums all;
            for (int z = lo.z(); z <= hi.z(); ++z)
                for (int y = lo.y(); y <= hi.y(); ++y)
                    for (int x = lo.x(); x <= hi.x(); ++x) {
                        const std::uint32_t o = index.find(cells::pack(Eigen::Array3i(x, y, z)));
                        if (o == cells::kNone) continue;
                        all.n += sums[o].n;
                        all.s += sums[o].s;
                        all.ss += sums[o].ss;
                    }
            Eigen::Vector3d n = Eigen::Vector3d::Zero();
            if (all.n >= 3) {
                const Eigen::Vector3d m = all.s / all.n;
                const Eigen::Matrix3d C = all.ss / all.n - m * m.transpose();
                if (C.trace() > 0) {
                    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es;
                    es.computeDirect(C);
                    n = es.eigenvectors().col(0).normalized();
                }
            }
            out.normals[c] = facing(n, out.points[c], viewpoint);
        }
    });
    return out;
}

Eigen::Vector3d facing(const Eigen::Vector3d& n, const Eigen::Vector3d& p, const Eigen::Vector3d& viewpoint) {
    const Eigen::Vector3d towards = viewpoint - p;
    if (n.squaredNorm() == 0.0)
        return towards.squaredNorm() > 0 ? Eigen::Vector3d(towards.normalized()) : Eigen::Vector3d::UnitZ();
    return n.dot(towards) < 0.0 ? Eigen::Vector3d(-n) : n;
}

void orient_towards(const std::vector<Eigen::Vector3d>& points, std::vector<Eigen::Vector3d>& normals,
                    const Eigen::Vector3d& viewpoint) {
    for (std::size_t i = 0; i < points.size() && i < normals.size(); ++i)
        normals[i] = facing(normals[i], points[i], viewpoint);
}

}  // namespace partloc
