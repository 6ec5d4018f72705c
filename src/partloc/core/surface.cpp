#include "partloc/core/surface.hpp"

#include <open3d/geometry/BoundingVolume.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <random>
#include <stdexcept>

namespace partloc {

int Surface::nearest(const Eigen::Vector3d& p, int k, double max_distance, int* indices,
                     double* squared_distances) const {
    if (parts.empty()) return grid.nearest(p, k, max_distance, indices, squared_distances);
    k = std::min(k, SampleGrid::kMaxK);
    int found = 0;
    int idx[SampleGrid::kMaxK];
    double d2[SampleGrid::kMaxK];
    for (const Part& part : parts) {
        // A part far from p answers from its grid's distance transform in one lookup.
        const int n = part.surface->grid.nearest(part.T_part_this * p, k, max_distance, idx, d2);
        // Into the k best so far (a part's answers are sorted, so most stop at once).
        for (int j = 0; j < n; ++j)
            if (!keep_nearest(part.first + idx[j], d2[j], k, found, indices, squared_distances)) break;
    }
    return found;
}

int Surface::nearest(const Eigen::Vector3d& p, double* squared_distance, double max_distance) const {
    int idx = -1;
    double d2 = 0.0;
    if (nearest(p, 1, max_distance, &idx, &d2) < 1) return -1;
    if (squared_distance) *squared_distance = d2;
    return idx;
}

double Surface::squared_distance(const Eigen::Vector3d& p, int index) const {
    if (parts.empty()) return (points[index] - p).squaredNorm();
    std::size_t g = parts.size() - 1;
    while (g > 0 && parts[g].first > index) --g;
    const Part& part = parts[g];
    return (part.surface->points[index - part.first] - part.T_part_this * p).squaredNorm();
}

NearestCache::NearestCache(const Surface& surface, std::size_t points, double reach)
    : surface_(surface), reach_(reach), entries_(points) {}

int NearestCache::nearest(std::size_t i, const Eigen::Vector3d& p, int k, double max_distance, int* indices,
                          double* squared_distances) {
    if (k <= 0) return 0;
    k = std::min(k, kListed - 1);
    Entry& e = entries_[i];
    const double max_d2 = max_distance * max_distance;
    if (e.listed >= 0 && max_distance <= reach_) {
        // Every sample not listed lies at least `free` from p.
        const double free = e.bound - (p - e.at).norm();
        if (free > 0) {
            int found = 0;
            for (int j = 0; j < e.listed; ++j) {
                const double d2 = surface_.squared_distance(p, e.index[j]);
                if (d2 <= max_d2) keep_nearest(e.index[j], d2, k, found, indices, squared_distances);
            }
            // The answer stands when no sample off the list can come nearer than its farthest (or, with
            // fewer than k, within max_distance): strictly, so that ties are not decided differently.
            const double last = found == k ? squared_distances[k - 1] : max_d2;
            if (last < free * free) return found;
        }
    }
    int idx[kListed];
    double d2[kListed];
    const double reach = std::max(reach_, max_distance);
    const int n = surface_.nearest(p, kListed, reach, idx, d2);
    ++e.searches;
    if (reach <= reach_) {
        e.at = p;
        // With kListed found, the others lie at least as far as the last; with fewer, beyond the reach. Less
        // a margin far above the rounding of the distances.
        e.bound = (n == kListed ? std::sqrt(d2[kListed - 1]) : reach) - 1e-9 * reach;
        e.listed = n;
        std::copy(idx, idx + n, e.index);
    }
    int found = 0;
    for (int j = 0; j < n && found < k && d2[j] <= max_d2; ++j, ++found) {
        indices[found] = idx[j];
        squared_distances[found] = d2[j];
    }
    return found;
}

std::size_t NearestCache::searches() const {
    std::size_t n = 0;
    for (const Entry& e : entries_) n += e.searches;
    return n;
}

void add_coarse_map(Surface& surface, double cell, double reach) {
    surface.coarse = std::make_shared<const NearestMap>(surface.points, cell, reach);
}

namespace {
/// make_surface, with `grid` built before for these points (null: built here).
Surface build_surface(std::shared_ptr<open3d::geometry::PointCloud> cloud, double spacing, SampleGrid* grid) {
    if (!cloud->HasNormals()) throw std::invalid_argument("surface samples need normals");
    Surface s;
    s.cloud = cloud;
    s.points = cloud->points_;
    s.normals = cloud->normals_;
    for (auto& n : s.normals) n.normalize();
    if (grid) {
        s.grid = std::move(*grid);
    } else if (!s.points.empty()) {
        // Without a spacing, that of samples spread over a surface of the bounding box's size.
        const double d = (cloud->GetMaxBound() - cloud->GetMinBound()).norm();
        const double grid_spacing =
            spacing > 0 ? spacing : std::max(d / std::sqrt(static_cast<double>(s.points.size())), 1e-9);
        s.grid = SampleGrid(s.points, grid_spacing);
    }
    if (!s.points.empty()) {
        const auto box = cloud->GetAxisAlignedBoundingBox();
        s.center = box.GetCenter();
        s.diameter = (box.max_bound_ - box.min_bound_).norm();
    }
    s.spacing = spacing;
    return s;
}
}  // namespace

Surface make_surface(std::shared_ptr<open3d::geometry::PointCloud> cloud, double spacing) {
    return build_surface(std::move(cloud), spacing, nullptr);
}

Surface make_surface(std::shared_ptr<open3d::geometry::PointCloud> cloud, double spacing, SampleGrid grid) {
    return build_surface(std::move(cloud), spacing, &grid);
}

Surface compose_surfaces(const std::vector<const Surface*>& parts,
                         const std::vector<Eigen::Isometry3d>& T_this_part) {
    if (parts.size() != T_this_part.size())
        throw std::invalid_argument("compose_surfaces: one pose per part");
    Surface s;
    s.cloud = std::make_shared<open3d::geometry::PointCloud>();
    s.spacing = std::numeric_limits<double>::infinity();
    for (std::size_t g = 0; g < parts.size(); ++g) {
        const Surface& part = *parts[g];
        if (!part.parts.empty()) throw std::invalid_argument("compose_surfaces: a part is itself composed");
        const Eigen::Isometry3d& F = T_this_part[g];
        s.parts.push_back({&part, F.inverse(), static_cast<int>(s.points.size())});
        for (std::size_t i = 0; i < part.points.size(); ++i) {
            s.points.push_back(F * part.points[i]);
            s.normals.push_back(F.linear() * part.normals[i]);
        }
        s.spacing = std::min(s.spacing, part.spacing);
    }
    if (!std::isfinite(s.spacing)) s.spacing = 0.0;
    s.cloud->points_ = s.points;
    s.cloud->normals_ = s.normals;
    if (!s.points.empty()) {
        const auto box = s.cloud->GetAxisAlignedBoundingBox();
        s.center = box.GetCenter();
        s.diameter = (box.max_bound_ - box.min_bound_).norm();
    }
    return s;
}

double mesh_area(const open3d::geometry::TriangleMesh& mesh) {
    double area = 0.0;
    for (const auto& t : mesh.triangles_) {
        const Eigen::Vector3d& a = mesh.vertices_[t(0)];
        area += 0.5 * (mesh.vertices_[t(1)] - a).cross(mesh.vertices_[t(2)] - a).norm();
    }
    return area;
}

namespace {

/// Lists of item indices by integer cell, in an open-addressing hash table that grows (load at most a half).
class CellLists {
  public:
    explicit CellLists(std::size_t expected) {
        std::size_t n = 64;
        while (n < 2 * expected) n *= 2;
        slots_.assign(n, Slot{});
    }
    /// The last item pushed into the cell, or -1; next() walks back through the earlier ones.
    std::int64_t head(std::int64_t x, std::int64_t y, std::int64_t z) const {
        const Slot& s = slots_[find(x, y, z)];
        return s.used ? s.head : -1;
    }
    std::int64_t next(std::int64_t item) const { return next_[static_cast<std::size_t>(item)]; }
    /// Items are pushed as 0, 1, 2, ...
    void push(std::int64_t x, std::int64_t y, std::int64_t z, std::int64_t item) {
        if (2 * (used_ + 1) > slots_.size()) grow();
        Slot& s = slots_[find(x, y, z)];
        if (!s.used) {
            s = Slot{x, y, z, -1, true};
            ++used_;
        }
        next_.push_back(s.head);
        s.head = item;
    }

  private:
    struct Slot {
        std::int64_t x = 0, y = 0, z = 0, head = -1;
        bool used = false;
    };
    std::size_t find(std::int64_t x, std::int64_t y, std::int64_t z) const {
        std::uint64_t h = static_cast<std::uint64_t>(x) * 0x9E3779B97F4A7C15ull ^
                          static_cast<std::uint64_t>(y) * 0xC2B2AE3D27D4EB4Full ^
                          static_cast<std::uint64_t>(z) * 0x165667B19E3779F9ull;
        h ^= h >> 29;
        const std::size_t mask = slots_.size() - 1;
        for (std::size_t i = h & mask;; i = (i + 1) & mask) {
            const Slot& s = slots_[i];
            if (!s.used || (s.x == x && s.y == y && s.z == z)) return i;
        }
    }
    void grow() {
        std::vector<Slot> old;
        old.swap(slots_);
        slots_.assign(2 * old.size(), Slot{});
        for (const Slot& s : old)
            if (s.used) slots_[find(s.x, s.y, s.z)] = s;
    }
    std::vector<Slot> slots_;
    std::vector<std::int64_t> next_;
    std::size_t used_ = 0;
};

}  // namespace

std::shared_ptr<open3d::geometry::PointCloud> sample_mesh(const open3d::geometry::TriangleMesh& mesh,
                                                          double spacing, std::vector<int>* triangles) {
    if (mesh.triangles_.empty()) throw std::invalid_argument("mesh has no triangles");
    if (!(spacing > 0)) throw std::invalid_argument("sampling spacing must be > 0");
    if (triangles) triangles->clear();
    // Poisson-disk sampling by sample elimination (Yuksel 2015, as MeshLab's filter): dense uniform samples,
    // then, in random order, each is kept unless a kept one lies within the disk radius. Our own because
    // Open3D's SamplePointsPoissonDisk took 4 s for a 50 mm block at 0.5 mm (measured, 2 cores); a hash grid
    // makes this linear. A maximal disk set of radius r has about one sample per 1.6 r^2 (measured; the
    // hexagonal packing bound is 0.87 r^2), so r = 0.8 spacing gives about one sample per spacing^2.
    const double area = mesh_area(mesh);
    const double r = 0.8 * spacing;
    const auto n_init = static_cast<std::size_t>(std::clamp(6.0 * area / (spacing * spacing), 100.0, 2.0e7));
    open3d::geometry::TriangleMesh copy(mesh);
    copy.ComputeTriangleNormals();
    std::vector<double> cumulative(copy.triangles_.size());
    double acc = 0.0;
    for (std::size_t t = 0; t < copy.triangles_.size(); ++t) {
        const auto& tri = copy.triangles_[t];
        const Eigen::Vector3d& a = copy.vertices_[tri(0)];
        acc += 0.5 * (copy.vertices_[tri(1)] - a).cross(copy.vertices_[tri(2)] - a).norm();
        cumulative[t] = acc;
    }
    std::mt19937_64 rng(12345);  // models are sampled the same way every run
    std::uniform_real_distribution<double> u(0.0, 1.0);
    const double r2 = r * r;
    // The kept samples by cell of side 2 r, as linked lists in an open-addressing table: a conflict lies in
    // the cells that the cube of side 2 r around the dart overlaps, at most two a side (eight). This loop
    // tests millions of darts: std::unordered_map's lookups with a vector per cell took 0.28 of a job's 8.3 s
    // CPU (perf, seed 106), and cells of r (27 around the dart) 80 ms for fiducial A of seed 106 (232 k
    // darts) against 49 ms now. The same samples: each dart is tested against the same kept samples.
    const double inv = 1.0 / (2.0 * r);
    CellLists kept(static_cast<std::size_t>(n_init / 16));
    auto cloud = std::make_shared<open3d::geometry::PointCloud>();
    for (std::size_t i = 0; i < n_init; ++i) {
        const double pick = u(rng) * acc;
        const std::size_t t = static_cast<std::size_t>(
            std::lower_bound(cumulative.begin(), cumulative.end(), pick) - cumulative.begin());
        const auto& tri = copy.triangles_[std::min(t, copy.triangles_.size() - 1)];
        double a = u(rng), b = u(rng);
        if (a + b > 1.0) {
            a = 1.0 - a;
            b = 1.0 - b;
        }
        const Eigen::Vector3d& v0 = copy.vertices_[tri(0)];
        const Eigen::Vector3d p = v0 + a * (copy.vertices_[tri(1)] - v0) + b * (copy.vertices_[tri(2)] - v0);
        const auto cell = [&](double v) { return static_cast<std::int64_t>(std::floor(v * inv)); };
        const std::int64_t kx = cell(p.x()), ky = cell(p.y()), kz = cell(p.z());
        // The cells that the cube of side 2 r around the dart overlaps: its own and, on each axis, the
        // neighbour on the side where the cube crosses a cell boundary (if it does).
        const auto other = [&](double v, std::int64_t k) {
            return cell(v - r) < k ? k - 1 : (cell(v + r) > k ? k + 1 : k);
        };
        const std::int64_t xs[2] = {kx, other(p.x(), kx)}, ys[2] = {ky, other(p.y(), ky)},
                           zs[2] = {kz, other(p.z(), kz)};
        const int nx = xs[1] != kx ? 2 : 1, ny = ys[1] != ky ? 2 : 1, nz = zs[1] != kz ? 2 : 1;
        const auto conflicts = [&](std::int64_t x, std::int64_t y, std::int64_t z) {
            for (std::int64_t j = kept.head(x, y, z); j >= 0; j = kept.next(j))
                if ((cloud->points_[j] - p).squaredNorm() < r2) return true;
            return false;
        };
        // The dart's own cell first: late in the sampling most darts land next to a kept sample there.
        bool free = !conflicts(kx, ky, kz);
        for (int iz = 0; iz < nz && free; ++iz)
            for (int iy = 0; iy < ny && free; ++iy)
                for (int ix = 0; ix < nx && free; ++ix)
                    if (ix || iy || iz) free = !conflicts(xs[ix], ys[iy], zs[iz]);
        if (!free) continue;
        kept.push(kx, ky, kz, static_cast<std::int64_t>(cloud->points_.size()));
        cloud->points_.push_back(p);
        cloud->normals_.push_back(copy.triangle_normals_[std::min(t, copy.triangles_.size() - 1)]);
        if (triangles) triangles->push_back(static_cast<int>(std::min(t, copy.triangles_.size() - 1)));
    }
    return cloud;
}

}  // namespace partloc
