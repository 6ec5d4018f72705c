#pragma once
// The virtual machining cell (paper §3.1, Fig. 1), machine frame, mm, every axis at 0:
//   - the rotary A axis is the machine X axis through the origin; the chuck's jaw face is the plane x = 0
//     and the workpiece reaches from the jaws towards -x, to an outboard support;
//   - the trunnion (fixed housing, turning faceplate) and the chuck with four jaws are at x > 0;
//   - a pallet (top at z = pallet_top, a grid of tapped holes) lies under the workpiece, on a machine table;
//   - the fiducial blocks stand on the pallet (bottom face on its top) and do not move with A;
//   - the workpiece, chuck, jaws and faceplate turn with A.
#include <Eigen/Geometry>
#include <memory>
#include <string>
#include <vector>

#include "partloc/core/kinematics.hpp"
#include "partloc/sim/shapes.hpp"

namespace partloc::sim {

enum class BodyKind { Fixture, Fiducial, Workpiece };

/// One rigid body of the cell.
struct Body {
    std::string name;  ///< a fixture's name ("pallet", "jaw_1", ...), the fiducial's name, or "workpiece"
    BodyKind kind = BodyKind::Fixture;
    std::shared_ptr<const Mesh> mesh;  ///< watertight, in the body's own frame
    Eigen::Isometry3d T_machine_body = Eigen::Isometry3d::Identity();  ///< with every axis at 0
    std::vector<std::string> moves_with;                               ///< axes that carry it, base first
    /// Per triangle of `mesh`: 1 + the index of the workpiece reference face it lies on (0: +x wall,
    /// 1: +y wall, 2: floor), 0 elsewhere. Empty for bodies without reference faces.
    std::vector<int> face_tag;
};

struct Cell {
    Machine machine;
    std::vector<Body> bodies;

    /// Where `body` is at axis values q (SPEC "Machine axes"): T(q) = M_1(q_1) ... M_n(q_n) T(0).
    Eigen::Isometry3d T_machine_body(const Body& body, const AxisValues& q) const {
        return machine.motion(body.moves_with, q) * body.T_machine_body;
    }
    /// Index of the first body called `name`, or -1.
    int find(const std::string& name) const;
};

/// The fixed and turning parts of the cell around a workpiece. Defaults are the paper's set-up.
struct FixtureLayout {
    double pallet_top = -50.0;       ///< z of the pallet's top face (mm), below the workpiece's swing
    double pallet_thickness = 30.0;  ///< mm
    Eigen::Vector2d pallet_min = {-420.0, -150.0};  ///< pallet footprint, x and y (mm)
    Eigen::Vector2d pallet_max = {-20.0, 150.0};
    double hole_pitch = 50.8;   ///< mm; paper §3.2: "an array of holes, spaced at 50.8mm (2 inches)"
    double hole_size = 10.0;    ///< side of a square tapped-hole pocket (mm)
    double hole_depth = 15.0;   ///< mm
    double grip_y = 31.75;      ///< half width of the workpiece where the jaws hold it (mm)
    double grip_z = 31.75;      ///< half height of the workpiece where the jaws hold it (mm)
    double jaw_depth = 30.0;    ///< jaws reach from x = 0 to x = jaw_depth (mm)
    double support_x = -160.0;  ///< x of the outboard support's centre tip: the workpiece's free end (mm)
};

/// The A axis: rotary about the machine X axis through the origin (right-hand rule, degrees).
Machine make_trunnion_machine();

/// Adds the machine table, pallet, trunnion, chuck, jaws and outboard support to `cell`.
void add_fixtures(Cell& cell, const FixtureLayout& layout = {});

/// Adds a fiducial block standing where T_machine_fiducial puts it; it does not move with any axis.
void add_fiducial(Cell& cell, const std::string& name, std::shared_ptr<const Mesh> mesh_fiducial,
                  const Eigen::Isometry3d& T_machine_fiducial);

/// Adds the workpiece: `mesh_nominal` is the body at its nominal place in the machine frame (axes at 0),
/// `reference_faces_nominal` its three datum faces there. The body is put at its true place,
/// body_true = T_true * T_nominal^-1 * body_nominal, and turns with A.
void add_workpiece(Cell& cell, std::shared_ptr<const Mesh> mesh_nominal,
                   const std::array<Rect, 3>& reference_faces_nominal,
                   const Eigen::Isometry3d& T_machine_workpiece_nominal,
                   const Eigen::Isometry3d& T_machine_workpiece_true);

}  // namespace partloc::sim
