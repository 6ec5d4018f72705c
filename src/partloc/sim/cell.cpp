#include "partloc/sim/cell.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace partloc::sim {

int Cell::find(const std::string& name) const {
    for (std::size_t i = 0; i < bodies.size(); ++i)
        if (bodies[i].name == name) return static_cast<int>(i);
    return -1;
}

Machine make_trunnion_machine() {
    Machine m;
    Axis a;
    a.name = "A";
    a.type = AxisType::Rotary;
    a.direction = Eigen::Vector3d::UnitX();
    a.point = Eigen::Vector3d::Zero();
    m.axes.push_back(a);
    return m;
}

namespace {

/// Centres of a row of tapped holes on `pitch`, symmetric about `centre`, keeping `margin` to the ends.
std::vector<double> hole_centres(double lo, double hi, double centre, double pitch, double margin) {
    std::vector<double> c;
    for (double x = centre + 0.5 * pitch; x + margin <= hi; x += pitch) c.push_back(x);
    for (double x = centre - 0.5 * pitch; x - margin >= lo; x -= pitch) c.push_back(x);
    std::sort(c.begin(), c.end());
    return c;
}

/// Cell edges for holes of width `size` at `centres` inside [lo, hi]; `is_hole[k]` marks hole cells.
std::vector<double> hole_edges(double lo, double hi, const std::vector<double>& centres, double size,
                               std::vector<bool>& is_hole) {
    std::vector<double> e = {lo};
    is_hole.clear();
    for (double c : centres) {
        e.push_back(c - 0.5 * size);
        is_hole.push_back(false);
        e.push_back(c + 0.5 * size);
        is_hole.push_back(true);
    }
    e.push_back(hi);
    is_hole.push_back(false);
    return e;
}

/// A cylinder about the machine X axis, radius r, from x0 to x1.
std::shared_ptr<Mesh> x_cylinder(double r, double x0, double x1, int segments) {
    auto m = make_cylinder(r, x0, x1, segments);
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
    T.linear() = Eigen::AngleAxisd(M_PI / 2, Eigen::Vector3d::UnitY()).toRotationMatrix();  // z -> x
    m->Transform(T.matrix());
    return m;
}

void add(Cell& cell, const std::string& name, std::shared_ptr<const Mesh> mesh, bool turns_with_a) {
    Body b;
    b.name = name;
    b.kind = BodyKind::Fixture;
    b.mesh = std::move(mesh);
    if (turns_with_a) b.moves_with = {"A"};
    cell.bodies.push_back(std::move(b));
}

}  // namespace

void add_fixtures(Cell& cell, const FixtureLayout& L) {
    if (cell.machine.axes.empty()) cell.machine = make_trunnion_machine();
    const double pallet_bottom = L.pallet_top - L.pallet_thickness;
    using V3 = Eigen::Vector3d;
    using Box = Eigen::AlignedBox3d;
    add(cell, "table", make_box(Box(V3(-650, -320, pallet_bottom - 40), V3(360, 320, pallet_bottom))), false);

    // The pallet with its grid of tapped holes: planar clutter with many small pockets (paper §3.2).
    HeightField pallet;
    std::vector<bool> hole_x, hole_y;
    const double margin = 0.5 * L.hole_pitch;
    pallet.x_edges = hole_edges(L.pallet_min.x(), L.pallet_max.x(),
                                hole_centres(L.pallet_min.x(), L.pallet_max.x(),
                                             L.pallet_max.x() - L.hole_pitch, L.hole_pitch, margin),
                                L.hole_size, hole_x);
    pallet.y_edges = hole_edges(L.pallet_min.y(), L.pallet_max.y(),
                                hole_centres(L.pallet_min.y(), L.pallet_max.y(), 0.0, L.hole_pitch, margin),
                                L.hole_size, hole_y);
    pallet.bottom = pallet_bottom;
    for (int iy = 0; iy < pallet.ny(); ++iy)
        for (int ix = 0; ix < pallet.nx(); ++ix)
            pallet.top.push_back(hole_x[ix] && hole_y[iy] ? L.pallet_top - L.hole_depth : L.pallet_top);
    add(cell, "pallet", make_height_field_block(pallet), false);

    // Trunnion: the fixed housing and the faceplate that turns with A; the chuck on the faceplate.
    const double faceplate_r = std::min(75.0, pallet_bottom < 0 ? -pallet_bottom - 2.0 : 75.0);
    add(cell, "trunnion",
        make_box(Box(V3(L.jaw_depth + 85, -150, pallet_bottom), V3(L.jaw_depth + 190, 150, 160))), false);
    add(cell, "faceplate", x_cylinder(faceplate_r, L.jaw_depth + 50, L.jaw_depth + 85, 64), true);
    add(cell, "chuck", x_cylinder(faceplate_r - 5, L.jaw_depth, L.jaw_depth + 50, 64), true);
    const double reach = faceplate_r - 7, half = 11;
    add(cell, "jaw_1", make_box(Box(V3(0, L.grip_y, -half), V3(L.jaw_depth, reach, half))), true);
    add(cell, "jaw_2", make_box(Box(V3(0, -half, L.grip_z), V3(L.jaw_depth, half, reach))), true);
    add(cell, "jaw_3", make_box(Box(V3(0, -reach, -half), V3(L.jaw_depth, -L.grip_y, half))), true);
    add(cell, "jaw_4", make_box(Box(V3(0, -half, -reach), V3(L.jaw_depth, half, -L.grip_z))), true);

    // Outboard support: a tower on the pallet and its centre against the workpiece's free end.
    add(cell, "support", make_box(Box(V3(L.support_x - 45, -40, L.pallet_top), V3(L.support_x - 15, 40, 22))),
        false);
    add(cell, "support_centre", x_cylinder(8.0, L.support_x - 15, L.support_x, 32), false);
}

void add_fiducial(Cell& cell, const std::string& name, std::shared_ptr<const Mesh> mesh_fiducial,
                  const Eigen::Isometry3d& T_machine_fiducial) {
    if (cell.find(name) >= 0)
        throw std::invalid_argument("add_fiducial: a body called '" + name + "' exists");
    Body b;
    b.name = name;
    b.kind = BodyKind::Fiducial;
    b.mesh = std::move(mesh_fiducial);
    b.T_machine_body = T_machine_fiducial;
    cell.bodies.push_back(std::move(b));
}

void add_workpiece(Cell& cell, std::shared_ptr<const Mesh> mesh_nominal,
                   const std::array<Rect, 3>& reference_faces_nominal,
                   const Eigen::Isometry3d& T_machine_workpiece_nominal,
                   const Eigen::Isometry3d& T_machine_workpiece_true) {
    Body b;
    b.name = "workpiece";
    b.kind = BodyKind::Workpiece;
    b.face_tag =
        classify_triangles(*mesh_nominal, {reference_faces_nominal.begin(), reference_faces_nominal.end()});
    b.mesh = std::move(mesh_nominal);
    b.T_machine_body = T_machine_workpiece_true * T_machine_workpiece_nominal.inverse();
    b.moves_with = {"A"};
    cell.bodies.push_back(std::move(b));
}

}  // namespace partloc::sim
