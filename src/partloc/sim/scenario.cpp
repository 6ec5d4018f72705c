#include "partloc/sim/scenario.hpp"

#include <open3d/geometry/BoundingVolume.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <random>
#include <stdexcept>

#include "partloc/core/geometry.hpp"
#include "partloc/core/icp.hpp"
#include "partloc/sim/random.hpp"

namespace partloc::sim {

namespace {

constexpr double kInch = 25.4;

// Random streams of one scenario, so that adding draws to one stage leaves the others unchanged.
enum Stream : std::uint64_t { kShapes = 1, kPerturbation = 2, kViews = 3, kScanner = 4 };

/// A fiducial block: the paper's "part with a fiducial feature" (§3.2, Figs. 2-5).
struct FiducialDesign {
    std::string name;
    HeightField block;                                 ///< in block coordinates, bottom at z = 0
    int corner_ix = 1, corner_iy = 1;                  ///< its concave corner: the fiducial frame
    Eigen::Vector2d centre = Eigen::Vector2d::Zero();  ///< footprint centre on the pallet, machine x, y (mm)
    double yaw_deg = 0.0;                              ///< turn about the machine z axis (degrees)
};

struct Design {
    std::string scenario;
    FixtureLayout layout;
    HeightField workpiece;  ///< nominal, in the machine frame with every axis at 0
    int datum_ix = 1, datum_iy = 1;
    Eigen::Isometry3d T_true = Eigen::Isometry3d::Identity();
    std::vector<FiducialDesign> fiducials;
};

Eigen::Isometry3d T_block_fiducial(const FiducialDesign& f) {
    return corner_frame(f.block, f.corner_ix, f.corner_iy);
}

/// Block on the pallet: footprint centre at f.centre, turned by yaw, bottom on the pallet's top.
Eigen::Isometry3d T_machine_block(const FiducialDesign& f, double pallet_top) {
    const auto& b = f.block;
    const Eigen::Vector3d c(0.5 * (b.x_edges.front() + b.x_edges.back()),
                            0.5 * (b.y_edges.front() + b.y_edges.back()), b.bottom);
    return Eigen::Translation3d(f.centre.x(), f.centre.y(), pallet_top) *
           Eigen::AngleAxisd(f.yaw_deg * M_PI / 180.0, Eigen::Vector3d::UnitZ()) * Eigen::Translation3d(-c);
}

/// Radius of the circle around the footprint centre that holds the footprint (mm).
double footprint_radius(const HeightField& b) {
    return 0.5 * std::hypot(b.x_edges.back() - b.x_edges.front(), b.y_edges.back() - b.y_edges.front());
}

/// The final part (paper §3.4.2: "the desired final part"): the workpiece with a finishing allowance
/// taken off every face except the datum faces, cut free of the chuck.
HeightField final_part_of(const HeightField& wp, int dix, int diy, double allowance, double cut_x) {
    HeightField f = wp;
    f.x_edges.front() += allowance;
    f.x_edges.back() = std::min(f.x_edges.back(), cut_x);
    f.y_edges.front() += allowance;
    f.y_edges.back() -= allowance;
    f.bottom += allowance;
    const double floor = wp.top_at(dix, diy);
    for (int iy = 0; iy < f.ny(); ++iy)
        for (int ix = 0; ix < f.nx(); ++ix)
            if (f.top_at(ix, iy) > floor + 2 * allowance) f.top_at(ix, iy) -= allowance;
    try {
        check_height_field(f);
    } catch (const std::invalid_argument&) {
        return wp;
    }
    return f;
}

/// What a scan saw, by body and face.
struct Seen {
    std::array<std::size_t, 3> faces{};  ///< datum faces +x, +y, +z
    std::size_t workpiece = 0, outliers = 0;
    std::vector<std::size_t> body;  ///< true returns per body
    /// Per body, true returns on faces whose normal (body frame) is along x, y, z.
    std::vector<std::array<std::size_t, 3>> body_axis;
};

Seen count(const SimulatedScan& s, const Cell& cell) {
    Seen seen;
    seen.body.assign(cell.bodies.size(), 0);
    seen.body_axis.assign(cell.bodies.size(), {0, 0, 0});
    for (std::size_t i = 0; i < s.body.size(); ++i) {
        if (s.outlier[i]) {
            ++seen.outliers;
            continue;
        }
        const Body& b = cell.bodies[static_cast<std::size_t>(s.body[i])];
        ++seen.body[static_cast<std::size_t>(s.body[i])];
        const auto t = static_cast<std::size_t>(s.triangle[i]);
        if (b.kind == BodyKind::Workpiece) {
            ++seen.workpiece;
            if (!b.face_tag.empty() && b.face_tag[t] > 0)
                ++seen.faces[static_cast<std::size_t>(b.face_tag[t] - 1)];
        }
        if (b.kind == BodyKind::Fiducial && b.mesh->HasTriangleNormals()) {
            Eigen::Index axis;
            b.mesh->triangle_normals_[t].cwiseAbs().maxCoeff(&axis);
            ++seen.body_axis[static_cast<std::size_t>(s.body[i])][static_cast<std::size_t>(axis)];
        }
    }
    return seen;
}

/// How well a scan meets the requirements: >= 1 when it meets them all, else the worst shortfall ratio.
double view_score(const Seen& seen, const Cell& cell, const ScenarioOptions& o, double scale,
                  const std::array<std::size_t, 3>& face_required) {
    double faces = 1e9;
    for (int f = 0; f < 3; ++f)
        faces = std::min(faces, seen.faces[static_cast<std::size_t>(f)] /
                                    (scale * face_required[static_cast<std::size_t>(f)]));
    double fiducial = 0;
    for (std::size_t b = 0; b < cell.bodies.size(); ++b) {
        if (cell.bodies[b].kind != BodyKind::Fiducial) continue;
        double f = seen.body[b] / (scale * o.min_fiducial_points);
        for (auto n : seen.body_axis[b]) f = std::min(f, n / (scale * o.min_fiducial_axis_points));
        fiducial = std::max(fiducial, f);
    }
    return std::min(faces, fiducial);
}

/// True when `eye` is within 20 mm of a body's bounding box (the scanner head cannot be there).
bool inside_a_body(const Eigen::Vector3d& eye, const RayScene& scene) {
    const Cell& cell = scene.cell();
    for (const auto& b : cell.bodies) {
        const Eigen::Isometry3d T = cell.T_machine_body(b, scene.axes());
        Eigen::AlignedBox3d box;
        for (const auto& v : b.mesh->vertices_) box.extend(T * v);
        if (box.exteriorDistance(eye) < 20.0) return true;
    }
    return false;
}

struct View {
    Eigen::Isometry3d T_machine_scanner = Eigen::Isometry3d::Identity();
    SimulatedScan scan;
    double score = -1;
};

/// Picks an operator-like viewpoint (paper §4: "each position chosen by the operator in order to best
/// capture the test parts surfaces") and scans from it: aimed between the workpiece's datum corner and a
/// fiducial, from inside the octant the three datum faces face, at about the working distance. Candidates
/// are first checked with a sparse ray grid; a promising one is scanned in full and kept when the full scan
/// sees every datum face and a fiducial well, else the search goes on; at the end the best full scan wins.
View scan_from_a_good_view(const RayScene& scene, const Design& d, const ScenarioOptions& o,
                           const std::array<std::size_t, 3>& face_required, std::uint64_t seed,
                           int scan_index) {
    const Cell& cell = scene.cell();
    const Body& wp = cell.bodies[static_cast<std::size_t>(cell.find("workpiece"))];
    const Eigen::Isometry3d T_wp = cell.T_machine_body(wp, scene.axes());
    const Eigen::Isometry3d T_nominal = corner_frame(d.workpiece, d.datum_ix, d.datum_iy);
    const Eigen::Vector3d corner = T_wp * T_nominal.translation();
    const Eigen::Matrix3d normals = T_wp.linear() * T_nominal.linear();  // columns: datum face normals
    std::vector<Eigen::Vector3d> fiducial_centres;
    for (const auto& b : cell.bodies)
        if (b.kind == BodyKind::Fiducial)
            fiducial_centres.push_back(b.T_machine_body * b.mesh->GetAxisAlignedBoundingBox().GetCenter());

    ScannerSettings preview = o.scanner, full = o.scanner;
    preview.point_spacing *= o.preview_factor;
    const double scale = 1.0 / (o.preview_factor * o.preview_factor);
    full.seed = Rng(seed, (kScanner << 32) + static_cast<std::uint64_t>(scan_index)).next();
    Rng rng(seed, (kViews << 32) + static_cast<std::uint64_t>(scan_index));
    View best, best_preview;
    for (int attempt = 0; attempt < o.view_attempts; ++attempt) {
        Eigen::Vector3d v =
            normals * Eigen::Vector3d(rng.uniform(0.35, 1.0), rng.uniform(0.35, 1.0), rng.uniform(0.35, 1.0));
        v.normalize();
        if (v.z() < 0.4) continue;  // the scanner hangs above the work (paper Fig. 6)
        // Prefer a fiducial on the scanner's side of the workpiece: the workpiece hides those behind it.
        std::size_t pick = 0;
        for (std::size_t i = 1; i < fiducial_centres.size(); ++i)
            if ((fiducial_centres[i] - corner).dot(v) > (fiducial_centres[pick] - corner).dot(v)) pick = i;
        if (attempt % 3 == 2)
            pick = static_cast<std::size_t>(rng.integer(0, static_cast<int>(fiducial_centres.size()) - 1));
        const Eigen::Vector3d target = corner + rng.uniform(0.35, 0.6) * (fiducial_centres[pick] - corner);
        const Eigen::Vector3d eye = target + o.scanner.working_distance * rng.uniform(0.92, 1.08) * v;
        if (inside_a_body(eye, scene)) continue;
        const Eigen::Vector3d up(rng.uniform(-0.4, 0.4), rng.uniform(-0.4, 0.4), 1.0);
        const Eigen::Isometry3d T = look_at(eye, target, up);
        preview.seed = rng.next();
        const double guess = view_score(count(scan(scene, T, preview), cell), cell, o, scale, face_required);
        if (guess > best_preview.score) {
            best_preview.score = guess;
            best_preview.T_machine_scanner = T;
        }
        if (guess < 1.2) continue;  // the sparse grid's counts are rough: only promising views are scanned
        View view{T, scan(scene, T, full), 0.0};
        view.score = view_score(count(view.scan, cell), cell, o, 1.0, face_required);
        if (view.score >= 1.0) return view;
        if (view.score > best.score) best = std::move(view);
    }
    if (best.score < 0) {  // no candidate looked promising: scan the best-looking one
        best.T_machine_scanner = best_preview.T_machine_scanner;
        best.scan = scan(scene, best.T_machine_scanner, full);
        best.score = view_score(count(best.scan, cell), cell, o, 1.0, face_required);
    }
    return best;
}

ModelSource mesh_model(const std::string& file, std::shared_ptr<const Mesh> mesh) {
    ModelSource m;
    m.file = file;
    m.mesh = std::move(mesh);
    return m;
}

SimulatedJob build(const Design& d, const ScenarioOptions& o, std::uint64_t seed) {
    SimulatedJob out;
    Cell& cell = out.cell;
    cell.machine = make_trunnion_machine();
    add_fixtures(cell, d.layout);

    Job& job = out.job;
    job.units = "mm";
    job.scanner.point_spacing = o.scanner.point_spacing;
    job.scanner.noise = o.scanner.noise_sigma;
    job.machine = cell.machine;
    out.truth.scenario = d.scenario;
    out.truth.seed = seed;
    out.truth.units = "mm";

    for (const auto& f : d.fiducials) {
        const Eigen::Isometry3d T_bf = T_block_fiducial(f);
        auto mesh = make_height_field_block(f.block);
        mesh->Transform(T_bf.inverse().matrix());
        mesh->ComputeTriangleNormals(true);
        const Eigen::Isometry3d T_mf = T_machine_block(f, d.layout.pallet_top) * T_bf;
        add_fiducial(cell, f.name, mesh, T_mf);
        Fiducial jf;
        jf.name = f.name;
        jf.model = mesh_model("models/fiducial_" + f.name + ".stl", mesh);
        jf.T_machine_fiducial = T_mf;  // probed = true (paper §3.2: probed to 0.025 mm)
        job.fiducials.push_back(jf);
        out.truth.T_machine_fiducial[f.name] = T_mf;
    }

    const Eigen::Isometry3d T_nominal = corner_frame(d.workpiece, d.datum_ix, d.datum_iy);
    const auto faces = corner_faces(d.workpiece, d.datum_ix, d.datum_iy);
    add_workpiece(cell, make_height_field_block(d.workpiece), faces, T_nominal, d.T_true);
    out.truth.T_machine_workpiece = d.T_true;
    out.truth.T_machine_workpiece_nominal = T_nominal;
    std::array<std::size_t, 3> face_required{};
    for (int f = 0; f < 3; ++f) {
        out.truth.reference_area[f] = faces[f].u.cross(faces[f].v).norm();
        face_required[f] = required_face_points(o, out.truth, f);
    }

    Workpiece& w = job.workpiece;
    w.reference_surfaces =
        mesh_model("models/workpiece_reference.stl", make_rect_mesh({faces.begin(), faces.end()}));
    w.T_machine_workpiece = T_nominal;
    w.final_part =
        mesh_model("models/final_part.stl",
                   make_height_field_block(final_part_of(d.workpiece, d.datum_ix, d.datum_iy, 1.0, -2.0)));
    w.moves_with = {"A"};
    // Crop box: the workpiece between the support's centre and the jaws, with room for its misplacement.
    const double margin = 8.0;
    const auto& wp = d.workpiece;
    const double top = *std::max_element(wp.top.begin(), wp.top.end());
    w.region = Eigen::AlignedBox3d(
        Eigen::Vector3d(wp.x_edges.front() + 3.0, wp.y_edges.front() - margin, wp.bottom - margin),
        Eigen::Vector3d(-2.0, wp.y_edges.back() + margin, top + margin));

    int index = 0;
    for (double a : o.a_values) {
        const AxisValues q = {{"A", a}};
        const RayScene scene(cell, q);  // one scene per axis value
        for (int k = 0; k < o.scans_per_position; ++k, ++index) {
            View view = scan_from_a_good_view(scene, d, o, face_required, seed, index);
            const Eigen::Isometry3d& T = view.T_machine_scanner;
            SimulatedScan& sim = view.scan;
            char file[64];
            std::snprintf(file, sizeof file, "scans/scan_%02d.ply", index + 1);
            Scan js;
            js.file = file;
            js.points = sim.points;
            js.axes = q;
            job.scans.push_back(js);

            const Seen seen = count(sim, cell);
            ScanTruth st;
            st.file = file;
            st.axes = q;
            st.T_machine_scan = T;
            st.points = sim.points->points_.size();
            st.outliers = seen.outliers;
            st.workpiece_points = seen.workpiece;
            st.reference_points = seen.faces;
            for (std::size_t b = 0; b < cell.bodies.size(); ++b)
                if (cell.bodies[b].kind == BodyKind::Fiducial)
                    st.fiducial_points[cell.bodies[b].name] = seen.body[b];
            out.truth.scans.push_back(st);
            out.scans.push_back(std::move(sim));
        }
    }
    return out;
}

/// Paper workpiece (Fig. 11 re-imagined): a 2.5 in square bar from the outboard support to 30 mm inside the
/// jaws, with a step milled on top whose floor and two walls are the datum planes meeting at
/// (-76.20, -12.70, 20.32) mm (§4).
HeightField paper_workpiece() {
    HeightField w;
    const double h = 1.25 * kInch;  // half of the 2.5 in bar
    w.x_edges = {-160.0, -3.0 * kInch, -20.0, 30.0};
    w.y_edges = {-h, -0.5 * kInch, h};
    w.bottom = -h;
    w.top = {h, h, h, h, 0.8 * kInch, h};
    return w;
}

}  // namespace

std::size_t required_face_points(const ScenarioOptions& o, const Truth& truth, int face) {
    const double full = truth.reference_area.at(static_cast<std::size_t>(face)) /
                        (o.scanner.point_spacing * o.scanner.point_spacing);
    return std::min(o.min_face_points, static_cast<std::size_t>(o.min_face_coverage * full));
}

PaperPose paper_measured_pose(int test) {
    static const double table[5][6] = {{-77.47, -12.79, 20.67, 0.5, -0.1, 0.0},
                                       {-80.06, -10.41, 21.08, -6.8, 0.1, 0.0},
                                       {-78.81, -12.16, 20.31, -1.9, 0.3, 0.0},
                                       {-80.90, -11.59, 21.71, -3.1, 0.0, 0.0},
                                       {-78.78, -13.86, 19.75, 4.0, 0.0, 0.0}};
    if (test < 1 || test > 5)
        throw std::invalid_argument("paper test must be 1..5, got " + std::to_string(test));
    const auto& r = table[test - 1];
    return {{r[0], r[1], r[2]}, {r[3], r[4], r[5]}};
}

PaperPose paper_located_pose(int test) {
    static const double table[5][6] = {{-77.52, -13.00, 20.99, 0.7, 0.0, 0.2},
                                       {-80.13, -10.95, 21.49, -6.6, 0.2, 0.0},
                                       {-78.91, -12.44, 20.63, -1.9, 0.4, 0.0},
                                       {-80.97, -12.01, 22.11, -3.0, 0.0, 0.1},
                                       {-78.85, -14.16, 20.03, 4.2, 0.0, 0.3}};
    if (test < 1 || test > 5)
        throw std::invalid_argument("paper test must be 1..5, got " + std::to_string(test));
    const auto& r = table[test - 1];
    return {{r[0], r[1], r[2]}, {r[3], r[4], r[5]}};
}

PaperPose paper_nominal_pose() { return {{-76.20, -12.70, 20.32}, {0.0, 0.0, 0.0}}; }

SimulatedJob simulate_paper_test(int test, std::uint64_t seed, const ScenarioOptions& options) {
    const PaperPose measured = paper_measured_pose(test);
    Design d;
    d.scenario = "paper_test_" + std::to_string(test);
    d.workpiece = paper_workpiece();
    d.datum_ix = 1;
    d.datum_iy = 1;
    d.T_true = pose_from_origin_euler(measured.origin, measured.euler_deg);
    d.layout.grip_y = d.workpiece.y_edges.back();
    d.layout.grip_z = d.workpiece.top.front();
    d.layout.support_x = d.workpiece.x_edges.front();
    // Two step-shaped blocks of unique shape (§3.2, Figs. 3 and 5), aligned with the machine axes, one
    // behind and one in front of the workpiece so that scans from either side see one.
    FiducialDesign a;
    a.name = "A";
    a.block.x_edges = {0.0, 0.75 * kInch, 1.5 * kInch, 2.0 * kInch};
    a.block.y_edges = {0.0, 0.625 * kInch, 1.5 * kInch};
    a.block.top = {1.25 * kInch, 1.25 * kInch, 0.875 * kInch, 1.25 * kInch, 0.5 * kInch, 0.5 * kInch};
    a.centre = {-110.0, 78.0};
    a.yaw_deg = 0.0;
    FiducialDesign b;
    b.name = "B";
    b.block.x_edges = {0.0, 1.0 * kInch, 1.75 * kInch, 2.5 * kInch};
    b.block.y_edges = {0.0, 0.5 * kInch, 1.25 * kInch};
    b.block.top = {1.0 * kInch, 1.0 * kInch, 1.0 * kInch, 1.0 * kInch, 0.375 * kInch, 0.6875 * kInch};
    b.centre = {-62.0, -88.0};
    b.yaw_deg = -90.0;  // its corner faces the front, where the scanner stands when A turns the datum there
    d.fiducials = {a, b};
    return build(d, options, seed * 7919 + static_cast<std::uint64_t>(test));
}

namespace {

/// A random step block of footprint about 40-65 x 30-50 mm with a concave corner at cell (1, 1).
HeightField random_fiducial_block(Rng& rng) {
    for (;;) {
        HeightField b;
        const int nx = rng.integer(2, 3), ny = rng.integer(2, 3);
        const double W = rng.uniform(40, 65), D = rng.uniform(30, 50);
        auto edges = [&](int n, double L) {
            std::vector<double> e = {0.0};
            for (int i = 1; i < n; ++i) e.push_back(L * (i + rng.uniform(-0.25, 0.25)) / n);
            e.push_back(L);
            return e;
        };
        b.x_edges = edges(nx, W);
        b.y_edges = edges(ny, D);
        const double tall = rng.uniform(24, 42);
        b.top.assign(static_cast<std::size_t>(nx * ny), tall);
        b.top_at(1, 1) = rng.uniform(8, tall - 8);
        for (int iy = 0; iy < ny; ++iy)
            for (int ix = 0; ix < nx; ++ix)
                if (ix >= 1 && iy >= 1 && !(ix == 1 && iy == 1)) b.top_at(ix, iy) = rng.uniform(8, tall);
        if (rng.uniform() < 0.5 && nx == 3) b.top_at(2, 0) = rng.uniform(12, tall - 4);  // a further step
        try {
            check_height_field(b);
        } catch (const std::invalid_argument&) {
            continue;
        }
        if (is_concave_corner(b, 1, 1) && has_no_symmetry(b, 0.5)) return b;
    }
}

/// A random bar along the A axis, half size hy x hz, with a datum corner at cell (datum_ix, 1).
HeightField random_workpiece(Rng& rng, int& datum_ix) {
    for (;;) {
        HeightField w;
        const double hy = rng.uniform(20, 30), hz = rng.uniform(20, 30);
        const double x_free = rng.uniform(-190, -140), x_datum = rng.uniform(-100, -60),
                     x_end = rng.uniform(-35, -10);
        w.x_edges = {x_free};
        if (rng.uniform() < 0.5) w.x_edges.push_back(rng.uniform(x_free + 20, x_datum - 20));
        datum_ix = static_cast<int>(w.x_edges.size());
        w.x_edges.push_back(x_datum);
        if (rng.uniform() < 0.5) w.x_edges.push_back(rng.uniform(x_datum + 15, x_end - 10));
        w.x_edges.push_back(x_end);
        w.x_edges.push_back(30.0);  // into the jaws
        const double y_datum = rng.uniform(-hy + 10, hy - 25);
        w.y_edges = {-hy, y_datum};
        if (rng.uniform() < 0.4) w.y_edges.push_back(rng.uniform(y_datum + 16, hy - 6));
        w.y_edges.push_back(hy);
        w.bottom = -hz;
        const int nx = w.nx(), ny = w.ny();
        const double floor = hz - rng.uniform(9, 16);
        w.top.assign(static_cast<std::size_t>(nx * ny), hz);
        const bool l_section = rng.uniform() < 0.4;  // the step runs the whole length: an L-section bar
        for (int iy = 1; iy < ny; ++iy)
            for (int ix = datum_ix; ix < nx - 1; ++ix) {
                if (ix == datum_ix && iy == 1) {
                    w.top_at(ix, iy) = floor;
                } else if (l_section) {
                    w.top_at(ix, iy) = floor;
                } else {
                    const double r = rng.uniform();
                    w.top_at(ix, iy) = r < 0.35 ? floor : r < 0.7 ? hz : rng.uniform(floor - 8, hz - 3);
                }
            }
        if (l_section) {  // the L runs from the free end too, bar the datum wall
            for (int iy = 1; iy < ny; ++iy)
                for (int ix = 0; ix < datum_ix; ++ix) w.top_at(ix, iy) = iy == 1 ? hz : floor;
        }
        try {
            check_height_field(w);
        } catch (const std::invalid_argument&) {
            continue;
        }
        if (!is_concave_corner(w, datum_ix, 1) || !has_no_symmetry(w, 0.5)) continue;
        // Datum faces big enough to be probed and scanned: walls of 250 mm^2, a floor of 500 mm^2.
        const auto faces = corner_faces(w, datum_ix, 1);
        auto area = [](const Rect& r) { return r.u.cross(r.v).norm(); };
        if (area(faces[0]) >= 250 && area(faces[1]) >= 250 && area(faces[2]) >= 500) return w;
    }
}

}  // namespace

SimulatedJob simulate_random_cell(std::uint64_t seed, const ScenarioOptions& options) {
    Rng rng(seed, kShapes << 32);
    Design d;
    d.scenario = "random_cell";
    d.workpiece = random_workpiece(rng, d.datum_ix);
    d.datum_iy = 1;
    d.layout.grip_y = d.workpiece.y_edges.back();
    d.layout.grip_z = -d.workpiece.bottom;
    d.layout.support_x = d.workpiece.x_edges.front();
    const Eigen::Isometry3d T_nominal = corner_frame(d.workpiece, d.datum_ix, d.datum_iy);

    // Fiducials stand on the pallet beside the workpiece, clear of its swing and of each other, at least
    // one on each side.
    const int n = rng.integer(2, 3);
    const double swing = std::hypot(d.workpiece.y_edges.back(), d.workpiece.bottom) + 6.0;
    const double corner_x = T_nominal.translation().x();
    for (int i = 0; i < n; ++i) {
        FiducialDesign f;
        f.name = std::string(1, static_cast<char>('A' + i));
        for (int tries = 0;; ++tries) {
            f.block = random_fiducial_block(rng);
            const double r = footprint_radius(f.block);
            const double side = i == 0 ? 1.0 : i == 1 ? -1.0 : (rng.uniform() < 0.5 ? 1.0 : -1.0);
            // Near enough to the datum corner to share a scan with it (the field is 256 x 192 mm).
            const double y_lo = std::max(swing, 50.0) + r;
            const double y_hi = std::min(d.layout.pallet_max.y() - r - 5.0, y_lo + 40.0);
            const double x_lo = std::max(corner_x - 90.0, d.layout.pallet_min.x() + r + 5.0);
            const double x_hi = std::min(corner_x + 60.0, d.layout.pallet_max.x() - r - 5.0);
            if (y_lo > y_hi || x_lo > x_hi) throw std::logic_error("random cell: no room for a fiducial");
            f.centre = {rng.uniform(x_lo, x_hi), side * rng.uniform(y_lo, y_hi)};
            // Squared up with the machine axes within 20 degrees, as a fixture is (paper §3.2: aligned with a
            // dial indicator), in any of four headings.
            f.yaw_deg = 90.0 * rng.integer(0, 3) + rng.uniform(-20, 20);
            bool clear = true;
            for (const auto& g : d.fiducials) {
                const double W = f.block.x_edges.back() - g.block.x_edges.back();
                const double D = f.block.y_edges.back() - g.block.y_edges.back();
                if ((f.centre - g.centre).norm() < r + footprint_radius(g.block) + 5.0) clear = false;
                if (std::abs(W) + std::abs(D) < 4.0) clear = false;  // keep the shapes apart
            }
            if (clear) break;
            if (tries > 1000) throw std::logic_error("random cell: could not place the fiducials");
        }
        d.fiducials.push_back(f);
    }

    // The workpiece as fixtured: a few mm and degrees off nominal, turned mostly about the bar's axis, as
    // the paper's shims and turns did (Table 4).
    Rng p(seed, kPerturbation << 32);
    const Eigen::Vector3d dt(p.uniform(-3, 3), p.uniform(-3, 3), p.uniform(-2, 2));
    const Eigen::Vector3d de(p.uniform(-6, 6), p.uniform(-1, 1), p.uniform(-1, 1));
    d.T_true = pose_from_origin_euler(T_nominal.translation() + dt, de);
    return build(d, options, seed);
}

void disturb_probing(Job& job, std::uint64_t seed) {
    std::mt19937_64 rng(seed * 7919 + 17);
    std::normal_distribution<double> g(0.0, 1.0);
    for (auto& f : job.fiducials) {
        const double sigma = f.pose_sigma;
        const auto box = f.model.mesh->GetAxisAlignedBoundingBox();
        const double half = 0.5 * (box.max_bound_ - box.min_bound_).norm();
        Vector6d xi;
        xi << g(rng) * sigma / half, g(rng) * sigma / half, g(rng) * sigma / half, g(rng) * sigma,
            g(rng) * sigma, g(rng) * sigma;
        // About the block's centre: the rotation does not also shift it.
        const Eigen::Vector3d centre = f.T_machine_fiducial * box.GetCenter();
        Eigen::Isometry3d about = Eigen::Isometry3d::Identity();
        about.translation() = centre;
        f.T_machine_fiducial = about * twist_exp(xi) * about.inverse() * f.T_machine_fiducial;
    }
}

}  // namespace partloc::sim
