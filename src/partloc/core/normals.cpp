#include "partloc/core/normals.hpp"

#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <utility>

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

std::vector<Eigen::Vector3d> estimate_normals(const std::vector<Eigen::Vector3d>& points, double radius, int max_nn,
                                              const std::vector<std::size_t>* at) {
    const std::size_t n = at ? at->size() : points.size();
    std::vector<Eigen::Vector3d> out(n, Eigen::Vector3d::UnitZ());
    if (points.size() < 3 || !(radius > 0) || max_nn < 3) return out;
    // Cells of half the radius (RadiusGrid skips those wholly outside the ball). Cells of 0.5, 0.75 and 1
    // radius took the same time within 5 % on seed 106's first scan (`partloc_bench normals`).
    const RadiusGrid grid(points, 0.5 * radius);
    struct Buffers {
        std::vector<int> idx;
        std::vector<std::pair<double, int>> by_distance;
    };
    tbb::enumerable_thread_specific<Buffers> buffers;
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 256), [&](const tbb::blocked_range<std::size_t>& range) {
        Buffers& b = buffers.local();
        for (std::size_t i = range.begin(); i != range.end(); ++i) {
            const Eigen::Vector3d& p = points[at ? (*at)[i] : i];
            grid.within(p, radius, b.idx, false);
            if (b.idx.size() > static_cast<std::size_t>(max_nn)) {
                // The max_nn nearest; which of several at the same distance is taken does not matter here.
                b.by_distance.clear();
                for (int j : b.idx) b.by_distance.emplace_back((points[j] - p).squaredNorm(), j);
                std::nth_element(b.by_distance.begin(), b.by_distance.begin() + (max_nn - 1), b.by_distance.end());
                b.idx.resize(max_nn);
                for (int k = 0; k < max_nn; ++k) b.idx[k] = b.by_distance[k].second;
                // The sum below in a fixed order, whatever order nth_element left.
                std::sort(b.idx.begin(), b.idx.end());
            }
            const Eigen::Vector3d normal = pca_normal(points, b.idx);
            if (normal.squaredNorm() > 0) out[i] = normal;
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
