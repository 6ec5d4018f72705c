#include "partloc/core/stock.hpp"

#include <open3d/geometry/BoundingVolume.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <stdexcept>
#include <vector>

#include "partloc/core/cell_key.hpp"
#include "partloc/core/radius_grid.hpp"

namespace partloc {
namespace {

using cells::Key;
using cells::KeyIndex;
using cells::kNone;
using cells::Lattice;
using cells::pack;
using cells::unpack;

// Key -> index for the grid's corners and cells, in bricks of 4^3: a hash of the bricks (small enough to stay
// in cache) and a dense block of 64 indices each, so that a cell's neighbours are mostly in one block. With a
// hash of the keys themselves (cache misses) the whole build took 0.38 s on seed 106, with bricks 0.29 s
// (cells of one spacing, measured).
class BrickIndex {
  public:
    std::uint32_t find(Key key) const {
        const std::uint32_t b = bricks_.find(brick(key));
        return b == kNone ? kNone : values_[64 * static_cast<std::size_t>(b) + local(key)];
    }
    void set(Key key, std::uint32_t value) {
        std::uint32_t b = bricks_.find(brick(key));
        if (b == kNone) {
            b = static_cast<std::uint32_t>(values_.size() / 64);
            bricks_.add(brick(key), b);
            values_.resize(values_.size() + 64, kNone);
        }
        values_[64 * static_cast<std::size_t>(b) + local(key)] = value;
    }

  private:
    static Key brick(Key key) { return pack(unpack(key) / 4); }
    static int local(Key key) {
        const Eigen::Array3i c = unpack(key);
        return (c.x() & 3) | (c.y() & 3) << 2 | (c.z() & 3) << 4;
    }
    KeyIndex bricks_;
    std::vector<std::uint32_t> values_;
};

void sort_unique(std::vector<Key>& keys) {
    std::sort(keys.begin(), keys.end());
    keys.erase(std::unique(keys.begin(), keys.end()), keys.end());
}

// The IMLS distance of oriented points (Kolluri 2008): f(x) = sum w_i n_i.(x - p_i) / sum w_i, the weighted
// mean of the signed distances to the points' tangent planes, positive on the side the normals face. Weights
// (1 - d^2/R^2)^3 within the reach R: smooth like a Gaussian, and no point beyond R to visit.
struct FieldValue {
    double distance = 0.0;  ///< f(x), 0 where weight is 0
    double weight = 0.0;    ///< sum w_i
};

class ImlsField {
  public:
    /// `origin`: below every point and every position to be asked by more than `reach`.
    ImlsField(const std::vector<Eigen::Vector3d>& points, const std::vector<Eigen::Vector3d>& normals,
              const Eigen::Vector3d& origin, double reach)
        : buckets_{origin, reach}, reach_(reach) {
        // The points in cubes of the reach (sparse, sorted by key): a position's neighbours are in the 27
        // cubes around its own.
        std::vector<std::pair<Key, std::uint32_t>> order(points.size());
        for (std::size_t i = 0; i < points.size(); ++i)
            order[i] = {pack(buckets_.cell_of(points[i])), static_cast<std::uint32_t>(i)};
        std::sort(order.begin(), order.end());
        points_.reserve(points.size());
        normals_.reserve(points.size());
        for (std::size_t i = 0; i < order.size(); ++i) {
            if (i == 0 || order[i].first != order[i - 1].first) {
                bucket_index_.add(order[i].first, static_cast<std::uint32_t>(start_.size()));
                start_.push_back(static_cast<std::uint32_t>(i));
            }
            points_.push_back(points[order[i].second]);
            normals_.push_back(normals[order[i].second]);
        }
        start_.push_back(static_cast<std::uint32_t>(points.size()));
    }

    /// f at each position, from TBB's threads; each position's sum runs over its neighbours in one fixed
    /// order whatever the threads.
    std::vector<FieldValue> evaluate(const std::vector<Eigen::Vector3d>& at) const {
        // Positions in the same cube share their candidates: grouped by cube, each group gathers them once.
        std::vector<std::pair<Key, std::uint32_t>> order(at.size());
        for (std::size_t i = 0; i < at.size(); ++i)
            order[i] = {pack(buckets_.cell_of(at[i])), static_cast<std::uint32_t>(i)};
        std::sort(order.begin(), order.end());
        std::vector<std::size_t> group;
        for (std::size_t i = 0; i < order.size(); ++i)
            if (i == 0 || order[i].first != order[i - 1].first) group.push_back(i);
        group.push_back(order.size());
        std::vector<FieldValue> out(at.size());
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, group.size() - 1, 16),
                          [&](const tbb::blocked_range<std::size_t>& r) {
                              Candidates near;
                              for (std::size_t g = r.begin(); g != r.end(); ++g) {
                                  gather(unpack(order[group[g]].first), near);
                                  for (std::size_t k = group[g]; k < group[g + 1]; ++k)
                                      out[order[k].second] = value(at[order[k].second], near);
                              }
                          });
        return out;
    }

    /// The weight v's surface has at its nearest point, on the view that it is flat there: at distance f from
    /// a flat surface the weight is (1 - f^2/R^2)^4 of that on it. A corner's support then does not depend on
    /// how far from the surface the grid put it.
    double support(const FieldValue& v) const {
        const double u = 1.0 - v.distance * v.distance / (reach_ * reach_);
        return u > 0.05 ? v.weight / (u * u * u * u) : 0.0;
    }
    /// Weight that a flat surface with one point per spacing^2 gives on itself: the integral of w over it.
    double flat_weight(double spacing) const { return M_PI * reach_ * reach_ / (4.0 * spacing * spacing); }

  private:
    // The points of the 27 cubes around one, coordinates apart (the sums below read them in sequence).
    struct Candidates {
        std::vector<double> x, y, z, nx, ny, nz, np;  // np = n.p
        void clear() {
            for (auto* v : {&x, &y, &z, &nx, &ny, &nz, &np}) v->clear();
        }
    };
    void gather(const Eigen::Array3i& c, Candidates& out) const {
        out.clear();
        for (int z = -1; z <= 1; ++z)
            for (int y = -1; y <= 1; ++y)
                for (int x = -1; x <= 1; ++x) {
                    const std::uint32_t b = bucket_index_.find(pack(c + Eigen::Array3i(x, y, z)));
                    if (b == kNone) continue;
                    for (std::uint32_t i = start_[b]; i < start_[b + 1]; ++i) {
                        const Eigen::Vector3d& p = points_[i];
                        const Eigen::Vector3d& n = normals_[i];
                        out.x.push_back(p.x());
                        out.y.push_back(p.y());
                        out.z.push_back(p.z());
                        out.nx.push_back(n.x());
                        out.ny.push_back(n.y());
                        out.nz.push_back(n.z());
                        out.np.push_back(n.dot(p));
                    }
                }
    }
    // The weighted sums over the candidates: sum w_i, sum w_i n_i and sum w_i n_i.p_i, so that
    // sum w_i n_i.(x - p_i) = (sum w_i n_i).x - sum w_i n_i.p_i. A point beyond the reach weighs 0. With
    // `towards` (unit), each weight is also multiplied by (n_i.towards)^8 (0 for a normal turned away).
    struct Sums {
        double w = 0, nx = 0, ny = 0, nz = 0, np = 0;
        double distance(const Eigen::Vector3d& x) const {
            return (nx * x.x() + ny * x.y() + nz * x.z() - np) / w;
        }
    };
    template <bool kTowards>
    Sums sums(const Eigen::Vector3d& at, const Candidates& c, const Eigen::Vector3d& towards = {}) const {
        const double inv_r2 = 1.0 / (reach_ * reach_);
        Sums s;
        const std::size_t n = c.x.size();
        for (std::size_t i = 0; i < n; ++i) {
            const double dx = at.x() - c.x[i], dy = at.y() - c.y[i], dz = at.z() - c.z[i];
            // max(u, 0) without a branch: GCC compiled std::max to one, mispredicted for the half of the
            // candidates beyond the reach (5.2 ns a pair against 1.3 ns, measured).
            const double u = 1.0 - (dx * dx + dy * dy + dz * dz) * inv_r2;
            const double t = 0.5 * (u + std::abs(u));
            double w = t * t * t;
            if constexpr (kTowards) {
                const double cosine = c.nx[i] * towards.x() + c.ny[i] * towards.y() + c.nz[i] * towards.z();
                const double g = 0.5 * (cosine + std::abs(cosine)), g2 = g * g, g4 = g2 * g2;
                w *= g4 * g4;
            }
            s.w += w;
            s.nx += w * c.nx[i];
            s.ny += w * c.ny[i];
            s.nz += w * c.nz[i];
            s.np += w * c.np[i];
        }
        return s;
    }
    // f at x. Where the normals around x disagree (at an edge, where the plain mean bulges the surface out
    // towards the other face, and where the pipeline's normals, blended across the edge, round it in), once
    // more with each point weighted by how well its normal agrees with their mean, as robust IMLS does
    // (Oztireli, Guennebaud, Gross 2009; one reweighting step, (n_i.mean)^8 instead of their Gaussian).
    // Measured, 95th percentile of the vertices' distance to the truth, without -> with: a box sampled with
    // 0.03 mm noise 0.102 -> 0.038 mm, a cylinder 0.112 -> 0.037, a simulated cell's stock 0.082 -> 0.060
    // (tests/test_stock.cpp), seed 106's 0.073 -> 0.052 (partloc_bench stock). With cells of one spacing and
    // a reach of 4, powers 4 and 16 gave within 0.002 mm of 8, and a second step changed nothing.
    FieldValue value(const Eigen::Vector3d& at, const Candidates& c) const {
        const Sums plain = sums<false>(at, c);
        FieldValue v;
        v.weight = plain.w;
        if (!(plain.w > 0)) return v;
        v.distance = plain.distance(at);
        const Eigen::Vector3d mean(plain.nx, plain.ny, plain.nz);
        const double agreement = mean.norm() / plain.w;  // 1 when all normals agree
        // Where they agree within a few degrees the step is left out: on seed 106 that changed the figures by
        // < 0.001 mm and saved a quarter of the time (0.116 s against 0.155 s).
        if (agreement >= 0.995 || agreement == 0) return v;
        const Sums sharp = sums<true>(at, c, mean / mean.norm());
        if (sharp.w > 0) v.distance = sharp.distance(at);
        return v;
    }

    Lattice buckets_;
    double reach_;
    std::vector<Eigen::Vector3d> points_, normals_;  // in cube order
    KeyIndex bucket_index_;                          // cube key -> its number
    std::vector<std::uint32_t> start_;               // points of cube number b: [start_[b], start_[b + 1])
};

// Corner j of a cell, j = x + 2y + 4z.
Eigen::Array3i corner_offset(int j) { return {j & 1, j >> 1 & 1, j >> 2 & 1}; }

// The 12 edges of a cell as pairs of its corners.
constexpr std::array<std::array<int, 2>, 12> kCellEdges = {
    {{0, 1}, {2, 3}, {4, 5}, {6, 7}, {0, 2}, {1, 3}, {4, 6}, {5, 7}, {0, 4}, {1, 5}, {2, 6}, {3, 7}}};

// The grid cells that the surface crosses, found outward from the cells that hold points, with f at their
// corners. The grid is sparse: keys to indices.
class Band {
  public:
    /// `min_support`: a corner is defined where field.support() reaches it.
    Band(const ImlsField& field, const Lattice& lattice, double min_support)
        : field_(field), lattice_(lattice), min_support_(min_support) {}

    /// Grows the band from the cells of `points`: each round takes the cells that share an edge the surface
    /// crosses with a crossed cell of the round before, until no new one is crossed.
    void grow(const std::vector<Eigen::Vector3d>& points) {
        std::vector<Key> round(points.size());
        for (std::size_t i = 0; i < points.size(); ++i) round[i] = pack(lattice_.cell_of(points[i]));
        sort_unique(round);
        while (!round.empty()) {
            add_corners(round);
            std::vector<Key> next;
            for (Key k : round) {
                cell_index_.set(k, static_cast<std::uint32_t>(cells_.size()));
                cells_.push_back(k);
                crossed_.push_back(crossed(k, &next));
            }
            sort_unique(next);
            round.clear();
            for (Key k : next)
                if (cell_index_.find(k) == kNone) round.push_back(k);
        }
    }

    const Lattice& lattice() const { return lattice_; }
    /// The crossed cells, by key.
    std::vector<Key> crossed_cells() const {
        std::vector<Key> out;
        for (std::size_t i = 0; i < cells_.size(); ++i)
            if (crossed_[i]) out.push_back(cells_[i]);
        std::sort(out.begin(), out.end());
        return out;
    }
    /// f at corner c and whether it is defined there (false for a corner not evaluated).
    bool corner(const Eigen::Array3i& c, double* f) const {
        const std::uint32_t i = corner_index_.find(pack(c));
        if (i == kNone || !valid_[i]) return false;
        *f = value_[i];
        return true;
    }

  private:
    // Evaluates f at the corners of `cells` that have no value yet.
    void add_corners(const std::vector<Key>& cells) {
        std::vector<Key> fresh;
        for (Key k : cells)
            for (int j = 0; j < 8; ++j) {
                const Key c = pack(unpack(k) + corner_offset(j));
                if (corner_index_.find(c) == kNone) fresh.push_back(c);
            }
        sort_unique(fresh);
        std::vector<Eigen::Vector3d> at(fresh.size());
        for (std::size_t i = 0; i < fresh.size(); ++i) at[i] = lattice_.at(unpack(fresh[i]));
        const std::vector<FieldValue> v = field_.evaluate(at);
        for (std::size_t i = 0; i < fresh.size(); ++i) {
            corner_index_.set(fresh[i], static_cast<std::uint32_t>(value_.size()));
            value_.push_back(v[i].distance);
            valid_.push_back(field_.support(v[i]) >= min_support_);
        }
    }
    // Whether the surface crosses cell k: its corners all defined and on both sides. Adds the cells around
    // each edge it crosses to `around`.
    bool crossed(Key k, std::vector<Key>* around) const {
        const Eigen::Array3i c = unpack(k);
        std::array<double, 8> f;
        int inside = 0;
        for (int j = 0; j < 8; ++j) {
            if (!corner(c + corner_offset(j), &f[j])) return false;
            inside += f[j] < 0;
        }
        if (inside == 0 || inside == 8) return false;
        for (const auto& e : kCellEdges) {
            if ((f[e[0]] < 0) == (f[e[1]] < 0)) continue;
            const Eigen::Array3i low = c + corner_offset(e[0]);
            const int d = e[1] - e[0] == 1 ? 0 : (e[1] - e[0] == 2 ? 1 : 2);
            const int u = (d + 1) % 3, v = (d + 2) % 3;
            for (int a = 0; a < 2; ++a)
                for (int b = 0; b < 2; ++b) {
                    Eigen::Array3i o = low;
                    o[u] -= a;
                    o[v] -= b;
                    if ((o != c).any()) around->push_back(pack(o));
                }
        }
        return true;
    }

    const ImlsField& field_;
    Lattice lattice_;
    double min_support_;
    BrickIndex corner_index_, cell_index_;  // corner key -> its value_, cell key -> its cells_
    std::vector<Key> cells_;
    std::vector<double> value_;
    std::vector<std::uint8_t> valid_, crossed_;
};

// Surface nets: a vertex in each crossed cell at the mean of its edges' crossings (f linear along each edge).
// Moving it onto f = 0 along the field's normal as well put it farther from the true surface on seed 106
// (median 0.0160 against 0.0151 mm, 95th percentile 0.070 against 0.068 mm; measured with cells of one
// spacing, a reach of 4, before the reweighting at edges).
std::vector<Eigen::Vector3d> cell_vertices(const Band& band, const std::vector<Key>& cells) {
    std::vector<Eigen::Vector3d> at(cells.size());
    for (std::size_t i = 0; i < cells.size(); ++i) {
        const Eigen::Array3i c = unpack(cells[i]);
        std::array<double, 8> f;
        for (int j = 0; j < 8; ++j) band.corner(c + corner_offset(j), &f[j]);
        Eigen::Vector3d sum = Eigen::Vector3d::Zero();
        int crossings = 0;
        for (const auto& e : kCellEdges) {
            const double fa = f[e[0]], fb = f[e[1]];
            if ((fa < 0) == (fb < 0)) continue;
            const Eigen::Vector3d a = corner_offset(e[0]).cast<double>(),
                                  b = corner_offset(e[1]).cast<double>();
            sum += a + fa / (fa - fb) * (b - a);
            ++crossings;
        }
        at[i] = band.lattice().at(c) + band.lattice().edge * sum / crossings;
    }
    return at;
}

// A quad for each grid edge that the surface crosses, joining the vertices of its four cells when all four
// have one, as two triangles across the shorter diagonal, counter-clockwise seen from outside (f > 0). Each
// edge is taken from the one of its cells that lies lowest on the two axes across it.
std::vector<Eigen::Vector3i> edge_quads(const Band& band, const std::vector<Key>& cells,
                                        const std::vector<Eigen::Vector3d>& vertices) {
    BrickIndex vertex_of;
    for (std::size_t i = 0; i < cells.size(); ++i) vertex_of.set(cells[i], static_cast<std::uint32_t>(i));
    std::vector<Eigen::Vector3i> triangles;
    for (Key k : cells) {
        const Eigen::Array3i c = unpack(k);
        for (int d = 0; d < 3; ++d) {
            const int u = (d + 1) % 3, v = (d + 2) % 3;
            Eigen::Array3i low = c;
            ++low[u];
            ++low[v];
            Eigen::Array3i high = low;
            ++high[d];
            double fl, fh;
            if (!band.corner(low, &fl) || !band.corner(high, &fh) || (fl < 0) == (fh < 0)) continue;
            // The four cells around the edge, counter-clockwise about +d (u, v, d right-handed).
            std::array<int, 4> q;
            bool all = true;
            for (int j = 0; j < 4 && all; ++j) {
                Eigen::Array3i o = low;
                o[u] -= (j == 0 || j == 3);
                o[v] -= (j == 0 || j == 1);
                const std::uint32_t vi = vertex_of.find(pack(o));
                all = vi != kNone;
                q[j] = static_cast<int>(vi);
            }
            if (!all) continue;
            // Counter-clockwise about +d faces +d: right where the edge leaves the solid along +d.
            if (fl >= 0) std::swap(q[1], q[3]);
            if ((vertices[q[0]] - vertices[q[2]]).squaredNorm() <=
                (vertices[q[1]] - vertices[q[3]]).squaredNorm()) {
                triangles.emplace_back(q[0], q[1], q[2]);
                triangles.emplace_back(q[0], q[2], q[3]);
            } else {
                triangles.emplace_back(q[0], q[1], q[3]);
                triangles.emplace_back(q[1], q[2], q[3]);
            }
        }
    }
    return triangles;
}

// Leaves out the vertices that no triangle uses (a crossed cell whose edges' other cells are not all crossed:
// the farthest vertices from the true surface, seed 106 at 0.135 mm: 0.49 mm against 0.45 for those kept).
// Removing pieces of fewer than 20 triangles as well removed none on seed 106 at either spacing, and 6 of
// 64,600 triangles on tests/test_stock.cpp's cell: not done.
void remove_unused_vertices(open3d::geometry::TriangleMesh& mesh) {
    std::vector<int> new_index(mesh.vertices_.size(), -1);
    for (const auto& t : mesh.triangles_)
        for (int j = 0; j < 3; ++j) new_index[t[j]] = 0;
    std::vector<Eigen::Vector3d> vertices;
    for (std::size_t i = 0; i < new_index.size(); ++i)
        if (new_index[i] == 0) {
            new_index[i] = static_cast<int>(vertices.size());
            vertices.push_back(mesh.vertices_[i]);
        }
    for (auto& t : mesh.triangles_)
        for (int j = 0; j < 3; ++j) t[j] = new_index[t[j]];
    mesh.vertices_ = std::move(vertices);
}

// The spacing of the points on their surface: the side of the square each one covers, from the median number
// of points within 3 spacings of about 2000 of them (a flat disc's worth), starting from the scanner's
// `spacing` and measured again at the new one while it moves by more than a tenth. The merged points are
// sparser than the scanner's spacing: run.cpp takes every k-th point to keep 150 k before thinning them to
// that spacing (seed 106: 0.416 mm for 0.383; scanner spacing 0.135 mm: 0.32 mm), and weights that expect a
// point per spacing^2 of 0.135 mm found support almost nowhere (measured: 9 % of the scanned surface
// covered).
double surface_spacing(const std::vector<Eigen::Vector3d>& points, double spacing) {
    const RadiusGrid grid(points, spacing);
    const std::size_t step = std::max<std::size_t>(1, points.size() / 2000);
    std::vector<int> found;
    std::vector<double> counts;
    for (int round = 0; round < 4; ++round) {
        const double r = 3.0 * spacing;
        counts.clear();
        for (std::size_t i = 0; i < points.size(); i += step) {
            grid.within(points[i], r, found, false);
            counts.push_back(static_cast<double>(found.size()));
        }
        std::nth_element(counts.begin(), counts.begin() + counts.size() / 2, counts.end());
        const double measured = std::sqrt(M_PI * r * r / counts[counts.size() / 2]);
        const bool settled = std::abs(measured - spacing) < 0.1 * spacing;
        spacing = measured;
        if (settled) break;
    }
    return spacing;
}

}  // namespace

std::shared_ptr<open3d::geometry::TriangleMesh> build_stock(const open3d::geometry::PointCloud& points,
                                                            const StockSettings& st) {
    auto mesh = std::make_shared<open3d::geometry::TriangleMesh>();
    if (points.points_.size() < 100 || !points.HasNormals()) return mesh;
    if (!(st.spacing > 0)) throw std::invalid_argument("build_stock: the spacing must be > 0");
    const auto box = points.GetAxisAlignedBoundingBox();
    const double spacing = surface_spacing(points.points_, st.spacing);
    const double reach = st.radius * spacing;
    Lattice lattice;
    lattice.edge = std::max(st.voxel * spacing,
                            (box.GetMaxExtent() + 4 * reach) / static_cast<double>(cells::kMask / 2));
    // Room below the points for the band's growth and the field's cubes around it.
    lattice.origin = box.min_bound_ - Eigen::Vector3d::Constant(2 * reach + 4 * lattice.edge);
    const ImlsField field(points.points_, points.normals_, lattice.origin - Eigen::Vector3d::Constant(reach),
                          reach);
    Band band(field, lattice, st.min_support * field.flat_weight(spacing));
    band.grow(points.points_);
    const std::vector<Key> cells = band.crossed_cells();
    mesh->vertices_ = cell_vertices(band, cells);
    mesh->triangles_ = edge_quads(band, cells, mesh->vertices_);
    remove_unused_vertices(*mesh);
    mesh->ComputeTriangleNormals();
    return mesh;
}

std::shared_ptr<open3d::geometry::TriangleMesh> build_stock_poisson(
    const open3d::geometry::PointCloud& points, const StockSettings& st) {
    auto empty = std::make_shared<open3d::geometry::TriangleMesh>();
    if (points.points_.size() < 100 || !points.HasNormals()) return empty;
    const auto box = points.GetAxisAlignedBoundingBox();
    const double extent = box.GetMaxExtent();
    // Octree depth so that a cell is about two point spacings, within Open3D's practical range.
    const double cells = extent / std::max(2.0 * st.spacing, extent / 512.0);
    const int depth = std::clamp(static_cast<int>(std::ceil(std::log2(std::max(cells, 2.0)))), 5, 9);
    // One thread: with Open3D's own threads (-1) the mesh differed from run to run of the same job, and the
    // job took longer (seed 106 on 2 cores: 8.7-9.0 s against 7.3 s, measured at bc8e269).
    auto [mesh, density] =
        open3d::geometry::TriangleMesh::CreateFromPointCloudPoisson(points, depth, 0, 1.1f, false, 1);
    if (!mesh || mesh->vertices_.empty()) return empty;
    std::vector<double> sorted = density;
    const std::size_t q = static_cast<std::size_t>(st.density_quantile * (sorted.size() - 1));
    std::nth_element(sorted.begin(), sorted.begin() + q, sorted.end());
    const double cut = sorted[q];
    std::vector<bool> remove(density.size());
    for (std::size_t i = 0; i < density.size(); ++i) remove[i] = density[i] < cut;
    mesh->RemoveVerticesByMask(remove);
    open3d::geometry::AxisAlignedBoundingBox crop(box.min_bound_ - Eigen::Vector3d::Constant(2 * st.spacing),
                                                  box.max_bound_ + Eigen::Vector3d::Constant(2 * st.spacing));
    auto cropped = mesh->Crop(crop);
    cropped->ComputeTriangleNormals();
    return cropped;
}

}  // namespace partloc
