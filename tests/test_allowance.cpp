// The allowance map and the maxmin placement (core/allowance, core/placement) against known answers: a stock
// that is the final part grown by known, different amounts per face, tilted, scanned with noise 0.13 mm on
// every face but the bottom.
#include <gtest/gtest.h>
#include <open3d/geometry/TriangleMesh.h>

#include <cmath>
#include <random>

#include "partloc/core/allowance.hpp"
#include "partloc/core/normals.hpp"
#include "partloc/core/placement.hpp"
#include "partloc/pipeline/machining.hpp"

namespace partloc {
namespace {

constexpr double kSpacing = 0.38, kNoise = 0.13;
constexpr double kPi = 3.14159265358979323846;

AllowanceSettings settings() {
    AllowanceSettings s;
    s.spacing = kSpacing;
    s.noise = kNoise;
    return s;
}

/// A face of the stock: a rectangle (centre, outward normal, two half-extents along u and v).
struct Rect {
    Eigen::Vector3d c, n, u, v;
    double hu, hv;
};

struct Cell {
    std::shared_ptr<open3d::geometry::TriangleMesh> part;  // final part: box [0,60] x [0,40] x [0,30]
    std::vector<Rect> faces;                               // the stock's scanned faces (machine frame)
    ScannedStock stock;
};

/// The stock: the part's box grown by grow[-x, +x, -y, +y, +z] (the bottom flush and not scanned), turned
/// by `tilt` about the part's centre, its five faces sampled at kSpacing with noise kNoise along their
/// normals; the points' normals estimated from the points, as the pipeline does.
Cell make_cell(const std::array<double, 5>& grow, const Eigen::Matrix3d& tilt, unsigned seed = 7) {
    Cell cell;
    cell.part = open3d::geometry::TriangleMesh::CreateBox(60, 40, 30);
    const Eigen::Vector3d lo(-grow[0], -grow[2], 0.0), hi(60 + grow[1], 40 + grow[3], 30 + grow[4]);
    const Eigen::Vector3d centre(30, 20, 15);
    const Eigen::Vector3d mid = 0.5 * (lo + hi), half = 0.5 * (hi - lo);
    const auto at = [&](const Eigen::Vector3d& p) { return Eigen::Vector3d(centre + tilt * (p - centre)); };
    for (int axis = 0; axis < 3; ++axis)
        for (int side = -1; side <= 1; side += 2) {
            if (axis == 2 && side < 0) continue;  // the bottom, on the fixture: not scanned
            Eigen::Vector3d n = Eigen::Vector3d::Zero(), u = n, v = n;
            n[axis] = side;
            u[(axis + 1) % 3] = 1;
            v[(axis + 2) % 3] = 1;
            Eigen::Vector3d c = mid;
            c[axis] += side * half[axis];
            cell.faces.push_back(
                {at(c), tilt * n, tilt * u, tilt * v, half[(axis + 1) % 3], half[(axis + 2) % 3]});
        }
    std::mt19937 rng(seed);
    std::uniform_real_distribution<double> jitter(-0.5, 0.5);
    std::normal_distribution<double> noise(0.0, kNoise);
    std::vector<Eigen::Vector3d> pts;
    for (const Rect& f : cell.faces)
        for (double a = -f.hu; a <= f.hu; a += kSpacing)
            for (double b = -f.hv; b <= f.hv; b += kSpacing) {
                const double ja = std::clamp(a + jitter(rng) * kSpacing, -f.hu, f.hu);
                const double jb = std::clamp(b + jitter(rng) * kSpacing, -f.hv, f.hv);
                pts.push_back(f.c + ja * f.u + jb * f.v + noise(rng) * f.n);
            }
    std::vector<Eigen::Vector3d> normals = estimate_normals(pts, 3 * kSpacing, 30);
    const Eigen::Vector3d inside = centre + tilt * (mid - centre);
    for (std::size_t i = 0; i < pts.size(); ++i)
        if (normals[i].dot(pts[i] - inside) < 0) normals[i] = -normals[i];
    cell.stock = make_scanned_stock(std::move(pts), std::move(normals), settings());
    return cell;
}

/// The true allowance of the sample (p, n): along n to the stock face that faces its way; NaN for none.
double true_allowance(const Cell& cell, const Eigen::Vector3d& p, const Eigen::Vector3d& n) {
    for (const Rect& f : cell.faces)
        if (f.n.dot(n) > 0.7) return (f.c - p).dot(f.n) / n.dot(f.n);
    return std::numeric_limits<double>::quiet_NaN();
}

/// The least true allowance of the part's samples moved by T.
double true_least(const Cell& cell, const PartSamples& part, const Eigen::Isometry3d& T) {
    double least = std::numeric_limits<double>::infinity();
    for (std::size_t i = 0; i < part.points.size(); ++i) {
        const double a = true_allowance(cell, T * part.points[i], T.linear() * part.normals[i]);
        if (!std::isnan(a)) least = std::min(least, a);
    }
    return least;
}

Eigen::Matrix3d tilt_of(double deg_x, double deg_y, double deg_z) {
    return (Eigen::AngleAxisd(deg_z * kPi / 180, Eigen::Vector3d::UnitZ()) *
            Eigen::AngleAxisd(deg_y * kPi / 180, Eigen::Vector3d::UnitY()) *
            Eigen::AngleAxisd(deg_x * kPi / 180, Eigen::Vector3d::UnitX()))
        .toRotationMatrix();
}

TEST(Allowance, FacesOfABoxAreItsSixSides) {
    const auto box = open3d::geometry::TriangleMesh::CreateBox(60, 40, 30);
    const PartSamples part = sample_part(*box, kSpacing, 20.0);
    ASSERT_EQ(part.faces.size(), 6u);
    EXPECT_NEAR(part.faces[0].area, 60 * 40, 1e-9);  // largest first: top and bottom
    EXPECT_NEAR(part.faces[5].area, 40 * 30, 1e-9);
    for (std::size_t i = 0; i < part.points.size(); ++i) {
        const PartFace& f = part.faces[part.face[i]];
        EXPECT_NEAR(part.normals[i].dot(f.normal), 1.0, 1e-9);
        EXPECT_NEAR((part.points[i] - f.centre).dot(f.normal), 0.0, 1e-9);
    }
    EXPECT_EQ(face_name(part.faces[0], Eigen::Matrix3d::Identity()).substr(0, 8), "face 1 (");
}

// Per face: the least, mean and largest allowance within 0.02 mm of the truth at noise 0.13 mm, on a stock
// grown by 0.4 to 1.2 mm and tilted; the unscanned bottom unscanned, never a number.
TEST(Allowance, PerFaceWithinTwoHundredthsOfTheTruth) {
    const Cell cell = make_cell({0.4, 1.2, 0.8, 0.6, 1.0}, tilt_of(0.3, -0.2, 0.4));
    const PartSamples part = sample_part(*cell.part, kSpacing, 20.0);
    const AllowanceMap map = measure_allowance(part, Eigen::Isometry3d::Identity(), cell.stock, settings());
    ASSERT_EQ(map.faces.size(), 6u);
    for (std::size_t f = 0; f < part.faces.size(); ++f) {
        double lo = std::numeric_limits<double>::infinity(), hi = -lo, sum = 0;
        std::size_t count = 0;
        for (std::size_t i = 0; i < part.points.size(); ++i) {
            if (part.face[i] != static_cast<int>(f)) continue;
            const double t = true_allowance(cell, part.points[i], part.normals[i]);
            if (std::isnan(t)) {
                EXPECT_TRUE(std::isnan(map.allowance[i]))
                    << "an unscanned sample was given " << map.allowance[i];
                continue;
            }
            lo = std::min(lo, t);
            hi = std::max(hi, t);
            sum += t;
            ++count;
        }
        const FaceAllowance& a = map.faces[f];
        if (count == 0) {  // the bottom
            EXPECT_EQ(a.unscanned, a.samples);
            EXPECT_TRUE(std::isnan(a.min));
            continue;
        }
        // Samples whose line meets the stock face within a spacing or two of its edge, with too few of its
        // points beyond the line, are unscanned rather than read from a plane carried past the points
        // (plane_near: a neighbouring level read as stock; tests/test_machining_sim.cpp): 1.2-1.5 % here.
        EXPECT_LT(a.unscanned_fraction(), 0.02) << "face " << a.id;
        EXPECT_NEAR(a.min, lo, 0.02) << "face " << a.id;
        EXPECT_NEAR(a.max, hi, 0.02) << "face " << a.id;
        EXPECT_NEAR(a.mean, sum / count, 0.02) << "face " << a.id;
    }
    EXPECT_NEAR(map.all.unscanned_fraction(), 60.0 * 40 / (2 * (60 * 40 + 60 * 30 + 40 * 30)), 0.01);
}

// A final part that breaks out of the stock: negative where it does, found on the right face.
TEST(Allowance, BreakOutIsNegative) {
    const Cell cell = make_cell({0.5, -0.3, 0.5, 0.5, 0.5}, Eigen::Matrix3d::Identity());
    const PartSamples part = sample_part(*cell.part, kSpacing, 20.0);
    const AllowanceMap map = measure_allowance(part, Eigen::Isometry3d::Identity(), cell.stock, settings());
    ASSERT_GE(map.min_face, 0);
    EXPECT_NEAR(map.all.min, -0.3, 0.02);
    EXPECT_GT(part.faces[map.min_face].normal.x(), 0.99);
    EXPECT_NEAR(map.all.min_at.x(), 60.0, 1e-6);
}

// Translations only: the optimum is known in closed form (y: 0.7 each side, which sets the least allowance;
// x anywhere in [0.3, 0.5], where both x sides keep 0.7 or more; z free downwards, the bottom unscanned), and
// a brute-force search over a grid of moves on the true stock agrees.
TEST(Placement, TranslationsMaximiseTheLeastAllowance) {
    const Cell cell = make_cell({0.4, 1.2, 0.8, 0.6, 1.0}, Eigen::Matrix3d::Identity());
    const PartSamples part = sample_part(*cell.part, kSpacing, 20.0);
    const AllowanceMap located =
        measure_allowance(part, Eigen::Isometry3d::Identity(), cell.stock, settings());
    PlacementSettings ps;
    ps.free = {true, true, true, false, false, false};
    ps.max_translation = 1.0;
    const Placement p = place_maxmin(part, Eigen::Isometry3d::Identity(), Eigen::Isometry3d::Identity(),
                                     cell.stock, settings(), ps, located);
    ASSERT_TRUE(p.valid) << p.reason;
    double brute = -1e9;
    for (double dx = -1; dx <= 1; dx += 0.01)
        for (double dy = -1; dy <= 1; dy += 0.01) {
            if (dx * dx + dy * dy > 1) continue;
            brute = std::max(brute, std::min({0.4 + dx, 1.2 - dx, 0.8 + dy, 0.6 - dy}));
        }
    EXPECT_NEAR(brute, 0.7, 1e-9);
    EXPECT_NEAR(p.map.all.min, brute, 0.02);
    EXPECT_NEAR(true_least(cell, part, p.T_move), brute, 0.02);
    EXPECT_GE(p.T_move.translation().x(), 0.3 - 0.03);
    EXPECT_LE(p.T_move.translation().x(), 0.5 + 0.03);
    EXPECT_NEAR(p.T_move.translation().y(), -0.1, 0.03);
    EXPECT_TRUE(p.T_move.linear().isApprox(Eigen::Matrix3d::Identity(), 1e-12));  // rotations locked
    EXPECT_LE(p.translation, 1.0 + 1e-9);
    EXPECT_TRUE(p.fits);
}

// Locked degrees of freedom stay where they are; the limit on the move holds.
TEST(Placement, LockedAxesAndLimitsHold) {
    const Cell cell = make_cell({0.4, 1.2, 0.8, 0.6, 1.0}, tilt_of(0.0, 0.0, 0.5));
    const PartSamples part = sample_part(*cell.part, kSpacing, 20.0);
    const AllowanceMap located =
        measure_allowance(part, Eigen::Isometry3d::Identity(), cell.stock, settings());
    // The datum frame turned 90 degrees about z: its x is the machine's y.
    Eigen::Isometry3d datum = Eigen::Isometry3d::Identity();
    datum.linear() = tilt_of(0, 0, 90);
    datum.translation() = Eigen::Vector3d(30, 20, 0);
    PlacementSettings ps;
    ps.free = {true, false, false, false, false, false};  // only along the datum's x (the machine's y)
    ps.max_translation = 0.05;
    const Placement p =
        place_maxmin(part, Eigen::Isometry3d::Identity(), datum, cell.stock, settings(), ps, located);
    ASSERT_TRUE(p.valid) << p.reason;
    EXPECT_TRUE(p.T_move.linear().isApprox(Eigen::Matrix3d::Identity(), 1e-12));
    EXPECT_NEAR(p.T_move.translation().x(), 0.0, 1e-12);
    EXPECT_NEAR(p.T_move.translation().z(), 0.0, 1e-12);
    EXPECT_LE(std::abs(p.T_move.translation().y()), 0.05 + 1e-9);
    EXPECT_GE(p.map.all.min, located.all.min - 1e-12);
}

// All six degrees of freedom on a tilted stock: the least allowance is that of an independent search on the
// true stock planes. For a box, the least allowance of a face is at one of its corners (linear along the face
// but for the cosine of the turn), so the part is its 8 corners with their 3 faces' normals (20 rows: the
// bottom has no stock face); a grid of moves over all six degrees of freedom at once, 7 per axis, zoomed
// about its best point eight times.
TEST(Placement, SixDegreesOfFreedomMatchAnIndependentSearch) {
    const Cell cell = make_cell({0.4, 1.2, 0.8, 0.6, 1.0}, tilt_of(0.3, -0.2, 0.4), 11);
    const PartSamples part = sample_part(*cell.part, kSpacing, 20.0);
    const AllowanceMap located =
        measure_allowance(part, Eigen::Isometry3d::Identity(), cell.stock, settings());
    PlacementSettings ps;
    ps.max_translation = 2.0;
    ps.max_rotation_deg = 1.0;
    const Placement p = place_maxmin(part, Eigen::Isometry3d::Identity(), Eigen::Isometry3d::Identity(),
                                     cell.stock, settings(), ps, located);
    ASSERT_TRUE(p.valid) << p.reason;
    std::vector<std::pair<Eigen::Vector3d, Eigen::Vector3d>> rows;  // corner, outward normal
    for (int c = 0; c < 8; ++c) {
        const Eigen::Vector3d corner(c & 1 ? 60 : 0, c & 2 ? 40 : 0, c & 4 ? 30 : 0);
        for (int k = 0; k < 3; ++k) {
            Eigen::Vector3d n = Eigen::Vector3d::Zero();
            n[k] = corner[k] > 0 ? 1 : -1;
            if (k == 2 && n[k] < 0) continue;
            rows.emplace_back(corner, n);
        }
    }
    ASSERT_EQ(rows.size(), 20u);
    const auto value = [&](const std::array<double, 6>& x) {
        if (std::hypot(x[0], x[1], x[2]) > 2.0) return -1e9;
        const Eigen::Matrix3d R = tilt_of(x[3], x[4], x[5]);
        if (Eigen::AngleAxisd(R).angle() * 180 / kPi > 1.0) return -1e9;
        const Eigen::Vector3d t(x[0], x[1], x[2]);
        double least = 1e9;
        for (const auto& [corner, n] : rows)
            least = std::min(least, true_allowance(cell, R * corner + t, R * n));
        return least;
    };
    std::array<double, 6> best_x{}, half{2.0, 2.0, 2.0, 1.0, 1.0, 1.0};
    double best = value(best_x);
    for (int zoom = 0; zoom < 9; ++zoom) {
        const std::array<double, 6> centre = best_x;
        std::array<int, 6> i{};
        for (int flat = 0; flat < 7 * 7 * 7 * 7 * 7 * 7; ++flat) {
            int rest = flat;
            std::array<double, 6> y;
            for (int k = 0; k < 6; ++k) {
                i[k] = rest % 7;
                rest /= 7;
                y[k] = centre[k] + half[k] * (i[k] - 3) / 3.0;
            }
            const double v = value(y);
            if (v > best) {
                best = v;
                best_x = y;
            }
        }
        for (double& h : half) h *= 0.4;
    }
    EXPECT_GT(best, value({}) + 0.1);  // moving matters here
    EXPECT_NEAR(p.map.all.min, best, 0.02);
    EXPECT_GE(true_least(cell, part, p.T_move), best - 0.02);
    EXPECT_LE(p.translation, 2.0 + 1e-9);
    EXPECT_LE(p.rotation_deg, 1.0 + 1e-6);
}

// A stock too small for what is asked: insufficient, and where.
TEST(Placement, InsufficientStockSaysWhere) {
    const Cell cell = make_cell({0.4, 1.2, 0.8, 0.6, 1.0}, Eigen::Matrix3d::Identity());
    const PartSamples part = sample_part(*cell.part, kSpacing, 20.0);
    const AllowanceMap located =
        measure_allowance(part, Eigen::Isometry3d::Identity(), cell.stock, settings());
    PlacementSettings ps;
    ps.free = {true, true, true, false, false, false};
    ps.required = 0.9;  // the best is 0.7
    const Placement p = place_maxmin(part, Eigen::Isometry3d::Identity(), Eigen::Isometry3d::Identity(),
                                     cell.stock, settings(), ps, located);
    ASSERT_TRUE(p.valid) << p.reason;
    EXPECT_FALSE(p.fits);
    EXPECT_NEAR(p.map.all.min, 0.7, 0.02);
    ASSERT_GE(p.map.min_face, 0);
    // The y sides bind (0.8 + 0.6 mm between them): both at the least allowance. (The top, free to move in
    // z over an unscanned bottom, may be lowered to the same value, so the face named may be either.)
    int sides = 0;
    for (std::size_t f = 0; f < part.faces.size(); ++f)
        if (std::abs(part.faces[f].normal.y()) > 0.9) {
            ++sides;
            EXPECT_NEAR(p.map.faces[f].min, p.map.all.min, 0.03) << "face " << part.faces[f].id;
        }
    EXPECT_EQ(sides, 2);
    EXPECT_TRUE(std::abs(part.faces[p.map.min_face].normal.y()) > 0.9 ||
                part.faces[p.map.min_face].normal.z() > 0.9);
}

// The pipeline's stage on a job: the final part placed by maxmin (translations, limited), the placed frame
// the datum frame moved, the placed mesh where the samples are, the unscanned bottom warned of, and the
// required allowance that the stock cannot give named.
TEST(Machining, PlanOnAJobPlacesWarnsAndNamesWhere) {
    const Cell cell = make_cell({0.4, 1.2, 0.8, 0.6, 1.0}, Eigen::Matrix3d::Identity());
    open3d::geometry::PointCloud merged;
    merged.points_ = cell.stock.points;
    merged.normals_ = cell.stock.normals;
    Job job;
    job.workpiece.final_part = ModelSource{"part.stl", cell.part, nullptr};
    job.workpiece.T_machine_workpiece.translation() = Eigen::Vector3d(10, 0, 0);
    job.workpiece.placement.maxmin = true;
    job.workpiece.placement.free = {true, true, true, false, false, false};
    job.workpiece.placement.max_translation = 1.0;
    job.workpiece.allowance_min = 0.5;
    const Eigen::Isometry3d I = Eigen::Isometry3d::Identity();
    const MachiningResult m =
        plan_machining(job, merged, I, job.workpiece.T_machine_workpiece, kSpacing, kNoise);
    ASSERT_TRUE(m.available) << m.reason;
    EXPECT_TRUE(m.maxmin);
    EXPECT_TRUE(m.fits);
    EXPECT_NEAR(m.located.all.min, 0.4, 0.02);
    EXPECT_NEAR(m.map.all.min, 0.7, 0.02);
    EXPECT_NEAR(true_least(cell, m.part, m.T_move), 0.7, 0.02);
    EXPECT_LE(m.translation, 1.0 + 1e-9);
    EXPECT_TRUE(m.T_machine_part.isApprox(m.T_move * job.workpiece.T_machine_workpiece, 1e-12));
    ASSERT_TRUE(m.final_part_placed);
    Eigen::Vector3d lowest = Eigen::Vector3d::Constant(1e9);
    for (const auto& v : m.final_part_placed->vertices_) lowest = lowest.cwiseMin(v);
    EXPECT_TRUE(lowest.isApprox(m.T_move.translation(), 1e-9));  // the box's corner was at the origin
    ASSERT_EQ(m.face_names.size(), 6u);
    EXPECT_EQ(m.face_names[0].substr(0, 6), "face 1");
    ASSERT_EQ(m.warnings.size(), 1u);  // a fifth of the surface, the bottom, unscanned
    EXPECT_NE(m.warnings[0].find("seen by no scan"), std::string::npos) << m.warnings[0];

    job.workpiece.allowance_min = 0.9;  // more than the stock gives anywhere
    const MachiningResult short_of =
        plan_machining(job, merged, I, job.workpiece.T_machine_workpiece, kSpacing, kNoise);
    ASSERT_TRUE(short_of.available);
    EXPECT_FALSE(short_of.fits);
    bool named = false;
    for (const auto& w : short_of.warnings)
        named = named || w.find("insufficient stock") != std::string::npos;
    EXPECT_TRUE(named);

    job.workpiece.final_part->mesh = nullptr;  // points give no surface to measure
    job.workpiece.final_part->points = std::make_shared<open3d::geometry::PointCloud>(merged);
    const MachiningResult none =
        plan_machining(job, merged, I, job.workpiece.T_machine_workpiece, kSpacing, kNoise);
    EXPECT_FALSE(none.available);
    EXPECT_NE(none.reason.find("not a mesh"), std::string::npos) << none.reason;
}

}  // namespace
}  // namespace partloc
