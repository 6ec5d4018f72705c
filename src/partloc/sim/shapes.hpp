#pragma once
// Watertight solids for the virtual cell: boxes, cylinders and height-field blocks. Every mesh is closed,
// edge- and vertex-manifold, with counter-clockwise triangles seen from outside (outward normals), so its
// signed volume is positive. Lengths in mm.
#include <open3d/geometry/TriangleMesh.h>

#include <Eigen/Geometry>
#include <array>
#include <memory>
#include <vector>

namespace partloc::sim {

using Mesh = open3d::geometry::TriangleMesh;

/// Axis-aligned box.
std::shared_ptr<Mesh> make_box(const Eigen::AlignedBox3d& box);

/// Cylinder about the z axis: radius (mm), from z0 to z1 (mm), with `segments` flat facets.
std::shared_ptr<Mesh> make_cylinder(double radius, double z0, double z1, int segments = 48);

/// A block over a rectangular grid: cell (ix, iy) covers [x_edges[ix], x_edges[ix+1]] x [y_edges[iy],
/// y_edges[iy+1]] and rises from `bottom` to its own top. The paper's step-shaped fiducial blocks (§3.2,
/// Figs. 3 and 5) and its test workpiece (Fig. 11) are such blocks.
struct HeightField {
    std::vector<double> x_edges;  ///< cell boundaries along x, strictly increasing (mm)
    std::vector<double> y_edges;  ///< cell boundaries along y, strictly increasing (mm)
    std::vector<double> top;      ///< top of cell (ix, iy) is top[iy * nx() + ix], above `bottom` (mm)
    double bottom = 0.0;          ///< z of the flat bottom face (mm)

    int nx() const { return static_cast<int>(x_edges.size()) - 1; }
    int ny() const { return static_cast<int>(y_edges.size()) - 1; }
    double top_at(int ix, int iy) const { return top[static_cast<std::size_t>(iy * nx() + ix)]; }
    double& top_at(int ix, int iy) { return top[static_cast<std::size_t>(iy * nx() + ix)]; }
};

/// Throws std::invalid_argument when the sizes disagree, the edges do not increase, a top is not above the
/// bottom, or, at some height, two diagonal cells are solid and the other two are not (the solid would
/// touch itself along an edge and its surface would not be a manifold).
void check_height_field(const HeightField& hf);

/// The block's surface: each cell's top, vertical walls only where neighbouring tops differ, the outer
/// walls and the bottom. Walls are split where other walls meet them, so no vertex lies inside an edge
/// (no T-junctions) and the mesh is watertight. Throws as check_height_field.
std::shared_ptr<Mesh> make_height_field_block(const HeightField& hf);

/// Volume of the block (mm^3).
double volume(const HeightField& hf);

/// True when no rigid motion other than the identity maps the block onto itself, so that a fit of its
/// model has a unique answer (paper §2: "each possessing a unique geometry"). `tol` in mm.
bool has_no_symmetry(const HeightField& hf, double tol = 1e-6);

/// A planar parallelogram {origin + s u + t v : s, t in [0, 1]}; its outward normal is u x v.
struct Rect {
    Eigen::Vector3d origin = Eigen::Vector3d::Zero();
    Eigen::Vector3d u = Eigen::Vector3d::UnitX();
    Eigen::Vector3d v = Eigen::Vector3d::UnitY();

    Eigen::Vector3d normal() const { return u.cross(v).normalized(); }
    /// True when p lies on the rectangle within tol (mm).
    bool contains(const Eigen::Vector3d& p, double tol = 1e-6) const;
    Rect transformed(const Eigen::Isometry3d& T) const {
        return {T * origin, T.linear() * u, T.linear() * v};
    }
};

/// An open mesh of rectangles (two triangles each) with normals u x v.
std::shared_ptr<Mesh> make_rect_mesh(const std::vector<Rect>& rects);

/// True when cell (ix, iy) is the floor of a concave corner: its neighbours at -x, at -y and diagonally at
/// (-x, -y) are all taller, so its floor and the two walls above it are three mutually orthogonal planes
/// meeting at (x_edges[ix], y_edges[iy], top).
bool is_concave_corner(const HeightField& hf, int ix, int iy);

/// The frame at the concave corner of cell (ix, iy): origin where the three planes meet, axes along their
/// edges (block x, y, z; each axis is the outward normal of one face). Throws std::invalid_argument when the
/// cell is not a concave corner.
Eigen::Isometry3d corner_frame(const HeightField& hf, int ix, int iy);

/// The three faces at that corner, in block coordinates, ordered by their normal: [0] the wall facing +x,
/// [1] the wall facing +y, [2] the floor facing +z. Each spans the cell's side and the lower of the wall's
/// heights, so it lies wholly on the block's surface.
std::array<Rect, 3> corner_faces(const HeightField& hf, int ix, int iy);

/// For each triangle of `mesh`, 1 + the index of the rect in `rects` that holds all three of its vertices
/// (within tol, mm), or 0.
std::vector<int> classify_triangles(const Mesh& mesh, const std::vector<Rect>& rects, double tol = 1e-6);

/// Signed volume enclosed by a closed mesh (mm^3): positive when its normals point outward.
double signed_volume(const Mesh& mesh);

}  // namespace partloc::sim
