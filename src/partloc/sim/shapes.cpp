#include "partloc/sim/shapes.hpp"

#include <algorithm>
#include <cmath>
#include <map>
#include <stdexcept>
#include <string>
#include <tuple>

namespace partloc::sim {

namespace {

/// Collects vertices and triangles, orienting each triangle so that its normal agrees with the face's
/// outward direction.
class MeshBuilder {
  public:
    int vertex(const Eigen::Vector3d& p) {
        mesh_->vertices_.push_back(p);
        return static_cast<int>(mesh_->vertices_.size()) - 1;
    }
    void triangle(int a, int b, int c, const Eigen::Vector3d& outward) {
        const auto& V = mesh_->vertices_;
        const Eigen::Vector3d n = (V[b] - V[a]).cross(V[c] - V[a]);
        if (n.dot(outward) < 0) std::swap(b, c);
        mesh_->triangles_.emplace_back(a, b, c);
    }
    void quad(int a, int b, int c, int d, const Eigen::Vector3d& outward) {
        triangle(a, b, c, outward);
        triangle(a, c, d, outward);
    }
    const std::vector<Eigen::Vector3d>& vertices() const { return mesh_->vertices_; }
    std::shared_ptr<Mesh> finish() {
        mesh_->ComputeTriangleNormals(true);
        return mesh_;
    }

  private:
    std::shared_ptr<Mesh> mesh_ = std::make_shared<Mesh>();
};

}  // namespace

std::shared_ptr<Mesh> make_box(const Eigen::AlignedBox3d& box) {
    if (box.isEmpty() || (box.sizes().array() <= 0).any())
        throw std::invalid_argument("make_box: the box has no volume");
    MeshBuilder b;
    int v[8];
    for (int i = 0; i < 8; ++i)
        v[i] = b.vertex({i & 1 ? box.max().x() : box.min().x(), i & 2 ? box.max().y() : box.min().y(),
                         i & 4 ? box.max().z() : box.min().z()});
    b.quad(v[0], v[2], v[6], v[4], -Eigen::Vector3d::UnitX());
    b.quad(v[1], v[3], v[7], v[5], Eigen::Vector3d::UnitX());
    b.quad(v[0], v[1], v[5], v[4], -Eigen::Vector3d::UnitY());
    b.quad(v[2], v[3], v[7], v[6], Eigen::Vector3d::UnitY());
    b.quad(v[0], v[1], v[3], v[2], -Eigen::Vector3d::UnitZ());
    b.quad(v[4], v[5], v[7], v[6], Eigen::Vector3d::UnitZ());
    return b.finish();
}

std::shared_ptr<Mesh> make_cylinder(double radius, double z0, double z1, int segments) {
    if (!(radius > 0) || !(z1 > z0) || segments < 3)
        throw std::invalid_argument("make_cylinder: needs radius > 0, z1 > z0 and 3 or more segments");
    MeshBuilder b;
    const int c0 = b.vertex({0, 0, z0});
    const int c1 = b.vertex({0, 0, z1});
    std::vector<int> lo(segments), hi(segments);
    for (int i = 0; i < segments; ++i) {
        const double a = 2.0 * M_PI * i / segments;
        lo[i] = b.vertex({radius * std::cos(a), radius * std::sin(a), z0});
        hi[i] = b.vertex({radius * std::cos(a), radius * std::sin(a), z1});
    }
    for (int i = 0; i < segments; ++i) {
        const int j = (i + 1) % segments;
        const double a = 2.0 * M_PI * (i + 0.5) / segments;
        b.quad(lo[i], lo[j], hi[j], hi[i], {std::cos(a), std::sin(a), 0});
        b.triangle(c0, lo[j], lo[i], -Eigen::Vector3d::UnitZ());
        b.triangle(c1, hi[i], hi[j], Eigen::Vector3d::UnitZ());
    }
    return b.finish();
}

namespace {

/// Top of cell (ix, iy), or the bottom for a cell outside the grid (there is no solid there).
double top_or_bottom(const HeightField& hf, int ix, int iy) {
    if (ix < 0 || iy < 0 || ix >= hf.nx() || iy >= hf.ny()) return hf.bottom;
    return hf.top_at(ix, iy);
}

/// The heights at which the surface has vertices on the vertical line through grid vertex (i, j): the
/// bottom and the tops of the up to four cells around it, ascending.
std::vector<double> levels_at(const HeightField& hf, int i, int j) {
    std::vector<double> z = {hf.bottom};
    for (int dx = -1; dx <= 0; ++dx)
        for (int dy = -1; dy <= 0; ++dy)
            if (i + dx >= 0 && j + dy >= 0 && i + dx < hf.nx() && j + dy < hf.ny())
                z.push_back(hf.top_at(i + dx, j + dy));
    std::sort(z.begin(), z.end());
    z.erase(std::unique(z.begin(), z.end()), z.end());
    return z;
}

}  // namespace

void check_height_field(const HeightField& hf) {
    if (hf.x_edges.size() < 2 || hf.y_edges.size() < 2)
        throw std::invalid_argument("height field: needs at least one cell in x and in y");
    if (hf.top.size() != static_cast<std::size_t>(hf.nx() * hf.ny()))
        throw std::invalid_argument("height field: top has " + std::to_string(hf.top.size()) +
                                    " values for " + std::to_string(hf.nx() * hf.ny()) + " cells");
    for (const auto* edges : {&hf.x_edges, &hf.y_edges})
        for (std::size_t i = 1; i < edges->size(); ++i)
            if (!((*edges)[i] > (*edges)[i - 1]))
                throw std::invalid_argument("height field: edges must increase");
    for (double t : hf.top)
        if (!(t > hf.bottom)) throw std::invalid_argument("height field: every top must be above the bottom");
    // Cells around an interior grid vertex, in cyclic order SW, SE, NE, NW.
    for (int i = 1; i < hf.nx(); ++i)
        for (int j = 1; j < hf.ny(); ++j) {
            const double h[4] = {hf.top_at(i - 1, j - 1), hf.top_at(i, j - 1), hf.top_at(i, j),
                                 hf.top_at(i - 1, j)};
            const auto z = levels_at(hf, i, j);
            for (std::size_t k = 0; k + 1 < z.size(); ++k) {
                const double mid = 0.5 * (z[k] + z[k + 1]);
                bool s[4];
                for (int c = 0; c < 4; ++c) s[c] = h[c] > mid;
                if (s[0] == s[2] && s[1] == s[3] && s[0] != s[1])
                    throw std::invalid_argument(
                        "height field: diagonal cells touch only along an edge at grid vertex (" +
                        std::to_string(i) + ", " + std::to_string(j) + ")");
            }
        }
}

std::shared_ptr<Mesh> make_height_field_block(const HeightField& hf) {
    check_height_field(hf);
    const int nx = hf.nx(), ny = hf.ny();
    MeshBuilder b;
    // One vertex per (grid vertex, level), shared by every face that meets it.
    std::vector<std::vector<double>> levels((nx + 1) * (ny + 1));
    std::vector<std::vector<int>> ids((nx + 1) * (ny + 1));
    for (int j = 0; j <= ny; ++j)
        for (int i = 0; i <= nx; ++i) {
            const int g = j * (nx + 1) + i;
            levels[g] = levels_at(hf, i, j);
            for (double z : levels[g]) ids[g].push_back(b.vertex({hf.x_edges[i], hf.y_edges[j], z}));
        }
    auto vid = [&](int i, int j, double z) {
        const int g = j * (nx + 1) + i;
        const auto it = std::lower_bound(levels[g].begin(), levels[g].end(), z);
        return ids[g][static_cast<std::size_t>(it - levels[g].begin())];
    };
    // Vertices on the vertical line through grid vertex (i, j) between lo and hi, ascending.
    auto chain = [&](int i, int j, double lo, double hi) {
        const int g = j * (nx + 1) + i;
        std::vector<int> c;
        for (std::size_t k = 0; k < levels[g].size(); ++k)
            if (levels[g][k] >= lo && levels[g][k] <= hi) c.push_back(ids[g][k]);
        return c;
    };
    // A wall between grid vertices a and b from lo to hi: zip the two vertical chains together so every
    // vertex on either side is used (no T-junctions).
    auto wall = [&](int ia, int ja, int ib, int jb, double lo, double hi, const Eigen::Vector3d& outward) {
        const auto A = chain(ia, ja, lo, hi), B = chain(ib, jb, lo, hi);
        const auto& V = b.vertices();
        std::size_t p = 0, q = 0;
        while (p + 1 < A.size() || q + 1 < B.size()) {
            const bool advance_a =
                q + 1 >= B.size() || (p + 1 < A.size() && V[A[p + 1]].z() <= V[B[q + 1]].z());
            if (advance_a) {
                b.triangle(A[p], B[q], A[p + 1], outward);
                ++p;
            } else {
                b.triangle(A[p], B[q], B[q + 1], outward);
                ++q;
            }
        }
    };
    for (int iy = 0; iy < ny; ++iy)
        for (int ix = 0; ix < nx; ++ix) {
            const double t = hf.top_at(ix, iy);
            b.quad(vid(ix, iy, t), vid(ix + 1, iy, t), vid(ix + 1, iy + 1, t), vid(ix, iy + 1, t),
                   Eigen::Vector3d::UnitZ());
            const double z0 = hf.bottom;
            b.quad(vid(ix, iy, z0), vid(ix + 1, iy, z0), vid(ix + 1, iy + 1, z0), vid(ix, iy + 1, z0),
                   -Eigen::Vector3d::UnitZ());
        }
    // Walls on the lines y = y_edges[iy], between cell (ix, iy - 1) (south) and (ix, iy) (north).
    for (int iy = 0; iy <= ny; ++iy)
        for (int ix = 0; ix < nx; ++ix) {
            const double s = top_or_bottom(hf, ix, iy - 1), n = top_or_bottom(hf, ix, iy);
            if (s == n) continue;
            wall(ix, iy, ix + 1, iy, std::min(s, n), std::max(s, n),
                 Eigen::Vector3d(0, n > s ? -1.0 : 1.0, 0));
        }
    // Walls on the lines x = x_edges[ix], between cell (ix - 1, iy) (west) and (ix, iy) (east).
    for (int ix = 0; ix <= nx; ++ix)
        for (int iy = 0; iy < ny; ++iy) {
            const double w = top_or_bottom(hf, ix - 1, iy), e = top_or_bottom(hf, ix, iy);
            if (w == e) continue;
            wall(ix, iy, ix, iy + 1, std::min(w, e), std::max(w, e),
                 Eigen::Vector3d(e > w ? -1.0 : 1.0, 0, 0));
        }
    return b.finish();
}

double volume(const HeightField& hf) {
    check_height_field(hf);
    double v = 0;
    for (int iy = 0; iy < hf.ny(); ++iy)
        for (int ix = 0; ix < hf.nx(); ++ix)
            v += (hf.x_edges[ix + 1] - hf.x_edges[ix]) * (hf.y_edges[iy + 1] - hf.y_edges[iy]) *
                 (hf.top_at(ix, iy) - hf.bottom);
    return v;
}

namespace {

/// Height of the block at (x, y), or the bottom outside its footprint.
double height_at(const HeightField& hf, double x, double y) {
    const auto ix = std::upper_bound(hf.x_edges.begin(), hf.x_edges.end(), x) - hf.x_edges.begin() - 1;
    const auto iy = std::upper_bound(hf.y_edges.begin(), hf.y_edges.end(), y) - hf.y_edges.begin() - 1;
    return top_or_bottom(hf, static_cast<int>(ix), static_cast<int>(iy));
}

/// Midpoints between consecutive distinct values (merging values closer than tol).
std::vector<double> midpoints(std::vector<double> v, double tol) {
    std::sort(v.begin(), v.end());
    std::vector<double> m;
    for (std::size_t i = 1; i < v.size(); ++i)
        if (v[i] - v[i - 1] > tol) m.push_back(0.5 * (v[i] + v[i - 1]));
    return m;
}

}  // namespace

bool has_no_symmetry(const HeightField& hf, double tol) {
    check_height_field(hf);
    const double x0 = hf.x_edges.front(), x1 = hf.x_edges.back();
    const double y0 = hf.y_edges.front(), y1 = hf.y_edges.back();
    const double W = x1 - x0, D = y1 - y0, cx = 0.5 * (x0 + x1), cy = 0.5 * (y0 + y1);
    // A rigid symmetry maps faces that lie on the convex hull onto such faces of the same shape. If the
    // bottom (a W x D rectangle) is the only hull face of that shape, every symmetry keeps it in place and is
    // a turn about the vertical axis through the footprint's centre.
    const auto [tmin, tmax] = std::minmax_element(hf.top.begin(), hf.top.end());
    if (*tmax - *tmin <= tol) return false;     // a box
    auto flat = [&](bool along_x, int index) {  // the outer wall of row/column `index`, if it is a rectangle
        const int n = along_x ? hf.nx() : hf.ny();
        const double h0 = along_x ? hf.top_at(0, index) : hf.top_at(index, 0);
        for (int k = 0; k < n; ++k)
            if (std::abs((along_x ? hf.top_at(k, index) : hf.top_at(index, k)) - h0) > tol) return -1.0;
        return h0 - hf.bottom;
    };
    for (int side : {0, hf.ny() - 1})
        if (std::abs(flat(true, side) - D) <= tol) return false;  // a W x h wall congruent to the bottom
    for (int side : {0, hf.nx() - 1})
        if (std::abs(flat(false, side) - W) <= tol) return false;
    std::vector<std::pair<double, double>> turns = {{-1.0, 0.0}};  // (cos, sin) of 180 degrees
    if (std::abs(W - D) <= tol) turns.insert(turns.end(), {{0.0, 1.0}, {0.0, -1.0}});
    for (const auto& [c, s] : turns) {
        auto turn = [&, c = c, s = s](double x, double y) {
            return Eigen::Vector2d(cx + c * (x - cx) - s * (y - cy), cy + s * (x - cx) + c * (y - cy));
        };
        std::vector<double> xs = hf.x_edges, ys = hf.y_edges;
        for (double x : hf.x_edges)
            for (double y : hf.y_edges) {
                const Eigen::Vector2d p = turn(x, y);
                xs.push_back(p.x());
                ys.push_back(p.y());
            }
        bool same = true;
        for (double x : midpoints(xs, tol))
            for (double y : midpoints(ys, tol)) {
                const Eigen::Vector2d p = turn(x, y);
                if (std::abs(height_at(hf, x, y) - height_at(hf, p.x(), p.y())) > tol) same = false;
            }
        if (same) return false;
    }
    return true;
}

bool Rect::contains(const Eigen::Vector3d& p, double tol) const {
    const Eigen::Vector3d n = u.cross(v);
    const Eigen::Vector3d d = p - origin;
    if (std::abs(d.dot(n.normalized())) > tol) return false;
    // Solve d = s u + t v in the plane.
    Eigen::Matrix<double, 3, 2> A;
    A << u, v;
    const Eigen::Vector2d st = A.colPivHouseholderQr().solve(d);
    return st.x() >= -tol / u.norm() && st.x() <= 1 + tol / u.norm() && st.y() >= -tol / v.norm() &&
           st.y() <= 1 + tol / v.norm();
}

std::shared_ptr<Mesh> make_rect_mesh(const std::vector<Rect>& rects) {
    MeshBuilder b;
    for (const auto& r : rects) {
        const int a = b.vertex(r.origin), c = b.vertex(r.origin + r.u), d = b.vertex(r.origin + r.u + r.v),
                  e = b.vertex(r.origin + r.v);
        b.quad(a, c, d, e, r.u.cross(r.v));
    }
    return b.finish();
}

bool is_concave_corner(const HeightField& hf, int ix, int iy) {
    if (ix < 1 || iy < 1 || ix >= hf.nx() || iy >= hf.ny()) return false;
    const double t = hf.top_at(ix, iy);
    return hf.top_at(ix - 1, iy) > t && hf.top_at(ix, iy - 1) > t && hf.top_at(ix - 1, iy - 1) > t;
}

Eigen::Isometry3d corner_frame(const HeightField& hf, int ix, int iy) {
    if (!is_concave_corner(hf, ix, iy))
        throw std::invalid_argument("corner_frame: cell (" + std::to_string(ix) + ", " + std::to_string(iy) +
                                    ") is not the floor of a concave corner");
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
    T.translation() = Eigen::Vector3d(hf.x_edges[ix], hf.y_edges[iy], hf.top_at(ix, iy));
    return T;
}

std::array<Rect, 3> corner_faces(const HeightField& hf, int ix, int iy) {
    const Eigen::Vector3d o = corner_frame(hf, ix, iy).translation();
    const double t = o.z();
    const double dx = hf.x_edges[ix + 1] - hf.x_edges[ix], dy = hf.y_edges[iy + 1] - hf.y_edges[iy];
    const double wall_x = hf.top_at(ix - 1, iy) - t, wall_y = hf.top_at(ix, iy - 1) - t;
    return {Rect{o, {0, dy, 0}, {0, 0, wall_x}},  // facing +x
            Rect{o, {0, 0, wall_y}, {dx, 0, 0}},  // facing +y
            Rect{o, {dx, 0, 0}, {0, dy, 0}}};     // facing +z
}

std::vector<int> classify_triangles(const Mesh& mesh, const std::vector<Rect>& rects, double tol) {
    std::vector<int> tag(mesh.triangles_.size(), 0);
    for (std::size_t t = 0; t < mesh.triangles_.size(); ++t)
        for (std::size_t r = 0; r < rects.size() && tag[t] == 0; ++r) {
            const auto& tri = mesh.triangles_[t];
            if (rects[r].contains(mesh.vertices_[tri(0)], tol) &&
                rects[r].contains(mesh.vertices_[tri(1)], tol) &&
                rects[r].contains(mesh.vertices_[tri(2)], tol))
                tag[t] = static_cast<int>(r) + 1;
        }
    return tag;
}

double signed_volume(const Mesh& mesh) {
    double v = 0;
    for (const auto& t : mesh.triangles_)
        v += mesh.vertices_[t(0)].dot(mesh.vertices_[t(1)].cross(mesh.vertices_[t(2)]));
    return v / 6.0;
}

}  // namespace partloc::sim
