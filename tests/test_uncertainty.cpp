// The probing part of the uncertainty (pipeline/uncertainty), against answers worked by hand: a fiducial's
// probing error carried through the scans it fixes into the located part.
#include <gtest/gtest.h>
#include <open3d/geometry/TriangleMesh.h>

#include <cmath>
#include <vector>

#include "partloc/core/surface.hpp"
#include "partloc/pipeline/uncertainty.hpp"

using namespace partloc;

namespace {

// Three faces of a 40 mm corner at the origin (x = 0, y = 0, z = 0), as samples with normals.
std::shared_ptr<open3d::geometry::PointCloud> corner(double step) {
    auto c = std::make_shared<open3d::geometry::PointCloud>();
    for (double u = 1.0; u < 40.0; u += step)
        for (double v = 1.0; v < 40.0; v += step) {
            c->points_.emplace_back(0.0, u, v);
            c->normals_.emplace_back(1.0, 0.0, 0.0);
            c->points_.emplace_back(u, 0.0, v);
            c->normals_.emplace_back(0.0, 1.0, 0.0);
            c->points_.emplace_back(u, v, 0.0);
            c->normals_.emplace_back(0.0, 0.0, 1.0);
        }
    return c;
}

Fiducial block(const std::string& name, const Eigen::Vector3d& at, double sigma) {
    Fiducial f;
    f.name = name;
    f.model.mesh = open3d::geometry::TriangleMesh::CreateBox(20.0, 20.0, 20.0);  // (0,0,0)-(20,20,20)
    f.T_machine_fiducial = Eigen::Isometry3d::Identity();
    f.T_machine_fiducial.translation() = at;
    f.pose_sigma = sigma;
    return f;
}

struct Case {
    Job job;
    Surface reference;
    UncertaintyInputs in;
    WorkpieceResult w;
};

// Three scans of the corner, the part located at the nominal (origin at the machine's origin).
Case three_scans() {
    Case c;
    c.reference = make_surface(corner(1.0), 1.0);
    for (int i = 0; i < 3; ++i) c.in.scan_points.push_back(corner(1.5 + 0.25 * i));
    c.in.reference = &c.reference;
    c.in.fit_distance = 0.5;
    c.in.noise = 0.01;
    c.w.valid = true;
    return c;
}

// Every scan of `c` fixed by the fiducials `ks` (indices into c.job.fiducials), with these shares of each
// scan fit's JtJ.
void every_scan_fixed_by(Case& c, const std::vector<std::size_t>& ks, const std::vector<Matrix6d>& jtj) {
    for (std::size_t i = 0; i < c.in.scan_points.size(); ++i) {
        c.in.scan_fiducials.push_back(ks);
        c.in.scan_fiducial_jtj.push_back(jtj);
    }
}

}  // namespace

// Every scan fixed by one fiducial alone: its whole probing error moves every scan, and so the part, the
// same way. At the part's origin that is sigma in translation plus the turn (sigma over half the block's
// size) on the lever arm from the block's centre.
TEST(ProbingUncertainty, OneFiducialFixingEveryScanMovesThePartByItsWholeError) {
    Case c = three_scans();
    const double sigma = 0.01;
    c.job.fiducials.push_back(block("F", Eigen::Vector3d(100.0, 0.0, 0.0), sigma));
    Matrix6d H = Matrix6d::Identity();
    H(0, 1) = H(1, 0) = 0.3;  // any information: a scan fixed by one fiducial takes its error whole
    every_scan_fixed_by(c, {0}, {H});
    estimate_uncertainty(c.job, c.in, c.w);
    const auto& u = c.w.uncertainty;
    ASSERT_TRUE(u.available);
    const Eigen::Vector3d arm =
        Eigen::Vector3d::Zero() - Eigen::Vector3d(110.0, 10.0, 10.0);  // to the centre
    const double turn = sigma / (0.5 * std::sqrt(3.0) * 20.0);         // radians
    for (int a = 0; a < 3; ++a) {
        const double lever2 = arm.squaredNorm() - arm(a) * arm(a);
        EXPECT_NEAR(u.origin_probing(a), std::sqrt(sigma * sigma + turn * turn * lever2), 1e-9) << a;
        EXPECT_NEAR(u.euler_probing(a), turn * 180.0 / M_PI, 1e-9) << a;
    }
    // No noise and no registration error: the part does not move when a scan is left out. Nor does the
    // probing move it: the one fiducial's error moves every scan alike, with or without any one of them.
    EXPECT_LT(u.origin_scans.norm(), 1e-6);
    EXPECT_LT(u.origin_probing_in_scans.norm(), 1e-9);
    EXPECT_LT(u.euler_probing_in_scans.norm(), 1e-9);
    // The interval holds the probing: 1.96 sigma at least.
    for (int a = 0; a < 3; ++a) EXPECT_GE(u.origin(a), 1.96 * u.origin_probing(a) - 1e-12);
}

// Every scan fixed by two fiducials that hold it equally: each fiducial's error moves the scans by half,
// and the two errors are independent, so the part's probing variance is a quarter of each one's.
TEST(ProbingUncertainty, TwoFiducialsHoldingEachScanEquallyShareItsError) {
    Case one = three_scans(), two = three_scans();
    const double sigma = 0.01;
    one.job.fiducials.push_back(block("F", Eigen::Vector3d(100.0, 0.0, 0.0), sigma));
    two.job.fiducials.push_back(block("F", Eigen::Vector3d(100.0, 0.0, 0.0), sigma));
    two.job.fiducials.push_back(block("G", Eigen::Vector3d(-100.0, 50.0, 0.0), sigma));
    const Matrix6d H = Matrix6d::Identity();
    every_scan_fixed_by(one, {0}, {H});
    every_scan_fixed_by(two, {0, 1}, {H, H});
    estimate_uncertainty(one.job, one.in, one.w);
    // G alone, for its own share.
    Case g = three_scans();
    g.job.fiducials.push_back(block("G", Eigen::Vector3d(-100.0, 50.0, 0.0), sigma));
    every_scan_fixed_by(g, {0}, {H});
    estimate_uncertainty(g.job, g.in, g.w);
    estimate_uncertainty(two.job, two.in, two.w);
    ASSERT_TRUE(two.w.uncertainty.available);
    for (int a = 0; a < 3; ++a) {
        const double expect =
            0.5 * std::hypot(one.w.uncertainty.origin_probing(a), g.w.uncertainty.origin_probing(a));
        EXPECT_NEAR(two.w.uncertainty.origin_probing(a), expect, 1e-9) << a;
    }
}

// Every scan fixed by two fiducials, F holding only its position and G only its turn (as a far-off small
// block and a large one might): F's error moves the part only by the shift it makes at the machine's origin
// (its translation, and its turn about its own centre seen from the origin), and G's only by its turn. An
// even split of each scan's error (the rule before 1a57cfd) gives a quarter of each one's whole error.
TEST(ProbingUncertainty, EachFiducialMovesThePartOnlyInTheDirectionsItHolds) {
    Case c = three_scans();
    const double sigma = 0.01;
    const Eigen::Vector3d at_f(100.0, 0.0, 0.0), at_g(-100.0, 50.0, 0.0);
    c.job.fiducials.push_back(block("F", at_f, sigma));
    c.job.fiducials.push_back(block("G", at_g, sigma));
    const double e = 1e-9;
    Vector6d hf, hg;
    hf << e, e, e, 1, 1, 1;
    hg << 1, 1, 1, e, e, e;
    every_scan_fixed_by(c, {0, 1}, {Matrix6d(hf.asDiagonal()), Matrix6d(hg.asDiagonal())});
    estimate_uncertainty(c.job, c.in, c.w);
    const auto& u = c.w.uncertainty;
    ASSERT_TRUE(u.available);
    const double turn = sigma / (0.5 * std::sqrt(3.0) * 20.0);
    const Eigen::Vector3d centre_f = at_f + Eigen::Vector3d(10.0, 10.0, 10.0);
    for (int a = 0; a < 3; ++a) {
        // A turn w about F's centre c shifts the origin by c x w: per axis a, turn^2 (|c|^2 - c_a^2).
        const double shift2 = centre_f.squaredNorm() - centre_f(a) * centre_f(a);
        EXPECT_NEAR(u.origin_probing(a), std::sqrt(sigma * sigma + turn * turn * shift2), 1e-6) << a;
        EXPECT_NEAR(u.euler_probing(a), turn * 180.0 / M_PI, 1e-6) << a;
    }
}

// Scan 0 fixed by F alone, scans 1 and 2 by G alone, the three scans alike (each a third of the part's
// JtJ): the part takes d_F / 3 + 2 d_G / 3 of the fiducials' errors. Left out, scan 0 leaves d_G, scan 1 or
// 2 leaves d_F / 2 + d_G / 2; about their mean those scatter by (-1/3, 1/3) and twice (1/6, -1/6), so the
// jackknife, (m - 1) / m times their sum of squares, would see (var_F + var_G) / 9 from the probing alone:
// part of what the probing adds again.
TEST(ProbingUncertainty, ScansDifferingInTheirFiducialsCarryProbingIntoTheJackknife) {
    const double sigma = 0.01;
    const Eigen::Vector3d at_f(100.0, 0.0, 0.0), at_g(-100.0, 50.0, 0.0);
    auto alike = [] {
        Case c = three_scans();
        for (auto& s : c.in.scan_points) s = corner(1.5);
        return c;
    };
    // Each fiducial alone fixing every scan: its whole variance at the part.
    Case f = alike(), g = alike(), both = alike();
    f.job.fiducials.push_back(block("F", at_f, sigma));
    g.job.fiducials.push_back(block("G", at_g, sigma));
    both.job.fiducials = {block("F", at_f, sigma), block("G", at_g, sigma)};
    const Matrix6d H = Matrix6d::Identity();
    every_scan_fixed_by(f, {0}, {H});
    every_scan_fixed_by(g, {0}, {H});
    both.in.scan_fiducials = {{0}, {1}, {1}};
    both.in.scan_fiducial_jtj = {{H}, {H}, {H}};
    for (Case* c : {&f, &g, &both}) estimate_uncertainty(c->job, c->in, c->w);
    const auto& u = both.w.uncertainty;
    ASSERT_TRUE(u.available);
    ASSERT_EQ(u.scans, 3);
    for (int a = 0; a < 3; ++a) {
        const double vf = std::pow(f.w.uncertainty.origin_probing(a), 2),
                     vg = std::pow(g.w.uncertainty.origin_probing(a), 2);
        EXPECT_NEAR(u.origin_probing(a), std::sqrt(vf / 9.0 + 4.0 * vg / 9.0), 1e-6) << a;
        EXPECT_NEAR(u.origin_probing_in_scans(a), std::sqrt((vf + vg) / 9.0), 1e-6) << a;
        const double wf = std::pow(f.w.uncertainty.euler_probing(a), 2),
                     wg = std::pow(g.w.uncertainty.euler_probing(a), 2);
        EXPECT_NEAR(u.euler_probing_in_scans(a), std::sqrt((wf + wg) / 9.0), 1e-6) << a;
    }
}

// pose_sigma 0 means the fiducials' poses are exact: nothing from the probing.
TEST(ProbingUncertainty, ExactFiducialsAddNothing) {
    Case c = three_scans();
    c.job.fiducials.push_back(block("F", Eigen::Vector3d(100.0, 0.0, 0.0), 0.0));
    every_scan_fixed_by(c, {0}, {Matrix6d::Identity()});
    estimate_uncertainty(c.job, c.in, c.w);
    ASSERT_TRUE(c.w.uncertainty.available);
    EXPECT_EQ(c.w.uncertainty.origin_probing.norm(), 0.0);
    EXPECT_EQ(c.w.uncertainty.euler_probing.norm(), 0.0);
}

// The interval is never narrower than the noise's own 1.96 sigma: points on the surfaces exactly leave the
// jackknife nothing to scatter, and exact fiducials nothing from the probing, but a fit's information of
// 1e6 / mm^2 along each axis (and 1e8 / rad^2 about each) still leaves 0.001 mm and 1e-4 rad of noise
// (before, such an interval was 0: a jackknife of three or four scans can come out far below the noise).
TEST(ProbingUncertainty, TheIntervalIsNeverNarrowerThanTheNoise) {
    Case c = three_scans();
    c.job.fiducials.push_back(block("F", Eigen::Vector3d(100.0, 0.0, 0.0), 0.0));
    every_scan_fixed_by(c, {0}, {Matrix6d::Identity()});
    Vector6d info;
    info << 1e8, 1e8, 1e8, 1e6, 1e6, 1e6;  // twist [w, v] about the machine origin, the part's origin
    c.in.information = info.asDiagonal();
    estimate_uncertainty(c.job, c.in, c.w);
    const auto& u = c.w.uncertainty;
    ASSERT_TRUE(u.available);
    EXPECT_LT(u.origin_scans.norm(), 1e-6);
    for (int a = 0; a < 3; ++a) {
        EXPECT_NEAR(u.origin_noise(a), 0.001, 1e-12) << a;
        EXPECT_NEAR(u.euler_noise(a), 1e-4 * 180.0 / M_PI, 1e-12) << a;
        EXPECT_NEAR(u.origin(a), 1.96 * 0.001, 1e-9) << a;
        EXPECT_NEAR(u.euler_deg(a), 1.96 * 1e-4 * 180.0 / M_PI, 1e-9) << a;
    }
}
