// The datum hierarchy (issue 4; paper §5: primary, secondary, tertiary datum, 3-2-1): a corner whose
// tertiary face is not square to the others, where the datum fit must honour the primary and the
// simultaneous fit splits the difference; virtual cells with a known pose (scans merged at their true
// registration); the job fields; and the whole run from the command line.
#include <gtest/gtest.h>
#include <open3d/geometry/BoundingVolume.h>
#include <open3d/utility/Logging.h>
#include <unistd.h>

#include <Eigen/Eigenvalues>
#include <atomic>
#include <cstdio>
#include <fstream>
#include <nlohmann/json.hpp>
#include <random>
#include <sstream>

#include "partloc/core/datum_fit.hpp"
#include "partloc/core/geometry.hpp"
#include "partloc/core/workpiece_fit.hpp"
#include "partloc/io/cloud_io.hpp"
#include "partloc/io/job_io.hpp"
#include "partloc/io/job_writer.hpp"
#include "partloc/sim/scenario.hpp"
#include "test_note.hpp"
#include "test_util.hpp"

using namespace partloc;
using namespace partloc::test;
namespace fs = std::filesystem;

namespace {

double angle_deg(const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
    return std::atan2(a.cross(b).norm(), a.dot(b)) * 180.0 / M_PI;
}

/// Unit normal of the least-squares plane through the points, signed like `hint`.
Eigen::Vector3d plane_normal(const std::vector<Eigen::Vector3d>& pts, const Eigen::Vector3d& hint) {
    Eigen::Vector3d c = Eigen::Vector3d::Zero();
    for (const auto& p : pts) c += p;
    c /= static_cast<double>(pts.size());
    Eigen::Matrix3d C = Eigen::Matrix3d::Zero();
    for (const auto& p : pts) C += (p - c) * (p - c).transpose();
    const Eigen::Vector3d n = Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(C).eigenvectors().col(0);
    return n.dot(hint) < 0 ? -n : n;
}

Surface grid_surface(const Eigen::Isometry3d& T, const Eigen::Vector3d& origin, const Eigen::Vector3d& u,
                     const Eigen::Vector3d& v, double spacing) {
    auto cloud = std::make_shared<open3d::geometry::PointCloud>();
    const Eigen::Vector3d n = u.cross(v).normalized();
    for (double s = 0; s <= u.norm(); s += spacing)
        for (double t = 0; t <= v.norm(); t += spacing) {
            cloud->points_.push_back(T * (origin + s * u.normalized() + t * v.normalized()));
            cloud->normals_.push_back(T.linear() * n);
        }
    return make_surface(cloud, spacing);
}

/// The datum corner of a cast part, in its own frame: primary A the floor z = 0 (40 x 30), secondary B the
/// wall y = 0 (40 x 15), tertiary C the wall x = 0 (30 x 15) but tilted by `tilt_deg` about the y axis,
/// pivoting at its points' mean height, so that its least-squares position along x is still x = 0.
struct CastCorner {
    std::vector<Eigen::Vector3d> all, a, b, c;  ///< machine frame
};

CastCorner cast_corner(const Eigen::Isometry3d& T_true, double tilt_deg, double spacing, double sigma,
                       std::mt19937& rng) {
    std::uniform_real_distribution<double> u01(0.0, 1.0);
    std::normal_distribution<double> noise(0.0, sigma);
    CastCorner cc;
    const auto face = [&](double w, double h, auto place) {
        const int n = static_cast<int>(w * h / (spacing * spacing));
        std::vector<Eigen::Vector3d> pts;
        for (int i = 0; i < n; ++i) pts.push_back(place(w * u01(rng), h * u01(rng), noise(rng)));
        return pts;
    };
    const auto to_machine = [&](std::vector<Eigen::Vector3d>& pts) {
        for (auto& p : pts) p = T_true * p;
        cc.all.insert(cc.all.end(), pts.begin(), pts.end());
    };
    cc.a = face(40, 30, [](double x, double y, double e) { return Eigen::Vector3d(x, y, e); });
    cc.b = face(40, 15, [](double x, double z, double e) { return Eigen::Vector3d(x, e, z); });
    const double t = std::tan(tilt_deg * M_PI / 180.0);
    cc.c = face(30, 15, [](double y, double z, double e) { return Eigen::Vector3d(e, y, z); });
    double mean_z = 0;
    for (const auto& p : cc.c) mean_z += p.z() / static_cast<double>(cc.c.size());
    for (auto& p : cc.c) p.x() += t * (p.z() - mean_z);
    // Clutter: the underside and the tops behind the walls, away from the datum faces.
    auto under = face(40, 30, [](double x, double y, double e) { return Eigen::Vector3d(x, y, -25 + e); });
    auto top = face(40, 9, [](double x, double y, double e) { return Eigen::Vector3d(x, -10 + y, 15 + e); });
    to_machine(cc.a);
    to_machine(cc.b);
    to_machine(cc.c);
    to_machine(under);
    to_machine(top);
    return cc;
}

// A cast corner (cast_corner, spacing 0.3, noise 0.05) at a known pose, the nominal reference surfaces of
// its three faces, and the part fit's settings for it.
struct CornerCase {
    Eigen::Isometry3d N = pose_from_origin_euler({-76.2, -12.7, 20.32}, {0, 0, 0});
    Eigen::Isometry3d T_true = pose_from_origin_euler({-75.0, -13.5, 20.82}, {1.5, -0.4, 0.7});
    CastCorner corner;
    Surface reference;
    WorkpieceFitSettings ws;
};

CornerCase corner_case(unsigned seed) {
    CornerCase c;
    const double spacing = 0.3, sigma = 0.05, ds = 0.25;
    std::mt19937 rng(seed);
    c.corner = cast_corner(c.T_true, 0.0, spacing, sigma, rng);
    auto all = std::make_shared<open3d::geometry::PointCloud>();
    for (const Surface& f : {grid_surface(c.N, {0, 0, 0}, {40, 0, 0}, {0, 30, 0}, ds),
                             grid_surface(c.N, {0, 0, 0}, {0, 0, 15}, {40, 0, 0}, ds),
                             grid_surface(c.N, {0, 0, 0}, {0, 30, 0}, {0, 0, 15}, ds)}) {
        all->points_.insert(all->points_.end(), f.points.begin(), f.points.end());
        all->normals_.insert(all->normals_.end(), f.normals.begin(), f.normals.end());
    }
    c.reference = make_surface(all, ds);
    c.ws.spacing = spacing;
    c.ws.noise = sigma;
    return c;
}

}  // namespace

// The part's fit refuses points that scatter about the reference surfaces far more than the scanner's noise:
// that is what a fit that slid into the wrong place keeps (measured: seed 1150's old fit, 20.5 degrees off,
// RMS 0.17-0.19 mm against 0.08-0.10 for right fits, noise 0.13 mm). The same corner, its points scattered
// 0.05: accepted when the noise is said to be 0.05, refused when it is said to be 0.02.
TEST(PartFit, PointsScatteringFarMoreThanTheNoiseAreNotALocatedPart) {
    const CornerCase cs = corner_case(11);
    const CastCorner& corner = cs.corner;
    const Surface& reference = cs.reference;
    const Eigen::Isometry3d& N = cs.N;
    const Eigen::Isometry3d& T_true = cs.T_true;
    WorkpieceFitSettings ws = cs.ws;
    const WorkpieceFit right = fit_reference_surfaces(corner.all, reference, ws);
    EXPECT_TRUE(right.valid) << right.reason;
    EXPECT_LT(pose_error(right.T_located_nominal * N, T_true).translation, 0.02);
    ws.noise = 0.02;
    const WorkpieceFit refused = fit_reference_surfaces(corner.all, reference, ws);
    partloc::test::note("rmse %.4f with the noise said 0.05, %.4f with 0.02: %s\n", right.rmse, refused.rmse,
                        refused.reason.c_str());
    EXPECT_FALSE(refused.valid);
    EXPECT_NE(refused.reason.find("did not find the part"), std::string::npos) << refused.reason;
}

// Points on one face of the reference surfaces leave the part free to slide along it and turn about its
// normal: the fit refuses them for their conditioning, whatever residual they fit with. Two faces hold five
// degrees of freedom and are refused too; the three faces of the corner locate it. (In the pipeline this
// check stands behind the others: seed 1355's mirrored-fiducial scan reached it at 9525799 and is refuted
// earlier since 2aeaf0f; `MirroredFiducial.LoneScanPlacedByAMirrorImageIsNotRegisteredWrongly`.)
TEST(PartFit, PointsOnOneOrTwoFacesDoNotFixThePart) {
    const CornerCase cs = corner_case(13);
    const CastCorner& corner = cs.corner;
    const WorkpieceFit floor = fit_reference_surfaces(corner.a, cs.reference, cs.ws);
    std::vector<Eigen::Vector3d> two = corner.a;
    two.insert(two.end(), corner.b.begin(), corner.b.end());
    const WorkpieceFit floor_and_wall = fit_reference_surfaces(two, cs.reference, cs.ws);
    const WorkpieceFit all = fit_reference_surfaces(corner.all, cs.reference, cs.ws);
    partloc::test::note("conditioning: one face %.5f, two %.5f, three %.5f\n", floor.conditioning,
                        floor_and_wall.conditioning, all.conditioning);
    for (const WorkpieceFit* f : {&floor, &floor_and_wall}) {
        EXPECT_FALSE(f->valid);
        EXPECT_NE(f->reason.find("to fix all six degrees of freedom"), std::string::npos) << f->reason;
    }
    EXPECT_TRUE(all.valid) << all.reason;
    EXPECT_LT(pose_error(all.T_located_nominal * cs.N, cs.T_true).translation, 0.02);
}

TEST(DatumFit, HonoursThePrimaryWhereTheSimultaneousFitSplitsTheDifference) {
    const double spacing = 0.3, sigma = 0.05, tilt = 1.0;
    const Eigen::Isometry3d N = pose_from_origin_euler({-76.2, -12.7, 20.32}, {0, 0, 0});
    const Eigen::Isometry3d T_true = pose_from_origin_euler({-75.0, -13.5, 20.82}, {1.5, -0.4, 0.7});
    // The same points twice (same random stream), once with the tertiary face square, once tilted.
    std::mt19937 rng_square(7), rng_tilted(7);
    const CastCorner square = cast_corner(T_true, 0.0, spacing, sigma, rng_square);
    const CastCorner cc = cast_corner(T_true, tilt, spacing, sigma, rng_tilted);

    const double ds = 0.25;
    std::vector<DatumSurface> datums = {
        {"A", grid_surface(N, {0, 0, 0}, {40, 0, 0}, {0, 30, 0}, ds)},
        {"B", grid_surface(N, {0, 0, 0}, {0, 0, 15}, {40, 0, 0}, ds)},
        {"C", grid_surface(N, {0, 0, 0}, {0, 30, 0}, {0, 0, 15}, ds)},
    };
    auto all = std::make_shared<open3d::geometry::PointCloud>();
    for (const auto& d : datums) {
        all->points_.insert(all->points_.end(), d.surface.points.begin(), d.surface.points.end());
        all->normals_.insert(all->normals_.end(), d.surface.normals.begin(), d.surface.normals.end());
    }
    const Surface reference = make_surface(all, ds);

    WorkpieceFitSettings ws;
    ws.noise = sigma;
    ws.spacing = spacing;
    DatumFitSettings dst;
    dst.noise = sigma;
    dst.spacing = spacing;
    struct Fits {
        Eigen::Isometry3d sim, dat;
        DatumFit datum_fit;
        WorkpieceFit sim_fit;
    };
    const auto fit_both = [&](const CastCorner& corner) {
        Fits f;
        f.sim_fit = fit_reference_surfaces(corner.all, reference, ws);
        EXPECT_TRUE(f.sim_fit.valid) << f.sim_fit.reason;
        f.datum_fit = fit_datums(corner.all, datums, f.sim_fit.T_located_nominal, dst);
        EXPECT_TRUE(f.datum_fit.valid) << f.datum_fit.reason;
        EXPECT_TRUE(f.datum_fit.converged);
        f.sim = f.sim_fit.T_located_nominal * N;
        f.dat = f.datum_fit.T_located_nominal * N;
        return f;
    };
    const Fits s = fit_both(square), t = fit_both(cc);

    // Square faces: both fits find the true corner.
    const PoseError s_sim = pose_error(s.sim, T_true), s_dat = pose_error(s.dat, T_true);
    partloc::test::note(
        "square corner: pose error %.4f mm %.5f deg (datums), %.4f mm %.5f deg (simultaneous)\n",
        s_dat.translation, s_dat.rotation_deg, s_sim.translation, s_sim.rotation_deg);
    EXPECT_LT(s_dat.translation, 0.01);
    EXPECT_LT(s_dat.rotation_deg, 0.01);
    EXPECT_LT(s_sim.translation, 0.01);
    EXPECT_LT(s_sim.rotation_deg, 0.01);

    // Tilting the tertiary moves the datum fit only in the one degree of freedom the tertiary owns (the
    // translation along the edge A and B share, here unchanged as the face pivots about its middle): the
    // primary's and the secondary's axes stay where their own points put them. The simultaneous fit turns.
    const double z_dat = angle_deg(t.dat.linear().col(2), s.dat.linear().col(2));
    const double y_dat = angle_deg(t.dat.linear().col(1), s.dat.linear().col(1));
    const double z_sim = angle_deg(t.sim.linear().col(2), s.sim.linear().col(2));
    const PoseError t_sim = pose_error(t.sim, T_true), t_dat = pose_error(t.dat, T_true);
    const Eigen::Vector3d nA = plane_normal(cc.a, T_true.linear().col(2));
    partloc::test::note(
        "tertiary tilted %.1f deg: primary axis moved %.6f deg (datums) vs %.5f deg (simultaneous); "
        "secondary axis %.6f deg (datums); primary axis to the primary's own plane %.5f deg (datums) vs "
        "%.5f deg (simultaneous); pose error %.4f mm %.5f deg (datums) vs %.4f mm %.5f deg "
        "(simultaneous)\n",
        tilt, z_dat, z_sim, y_dat, angle_deg(t.dat.linear().col(2), nA), angle_deg(t.sim.linear().col(2), nA),
        t_dat.translation, t_dat.rotation_deg, t_sim.translation, t_sim.rotation_deg);
    for (const auto& d : t.datum_fit.datums)
        partloc::test::note("  datum %s: %zu points, rmse %.4f mm, %d dof, conditioning %.3f\n",
                            d.name.c_str(), d.points, d.rmse, d.dof, d.conditioning);
    EXPECT_LT(z_dat, 0.001);
    EXPECT_LT(y_dat, 0.001);
    EXPECT_LT((t.dat.translation() - s.dat.translation()).norm(), 0.002);
    EXPECT_GT(z_sim, 0.02);  // the simultaneous fit splits the difference...
    EXPECT_LT(z_sim, tilt);  // ... between the primary and the tertiary
    EXPECT_GT(z_sim, 20 * z_dat);
    EXPECT_LT(angle_deg(t.dat.linear().col(2), nA), 0.005);  // the primary's points' own plane, to noise
    EXPECT_LT(t_dat.translation, 0.01);
    EXPECT_LT(t_dat.rotation_deg, 0.01);
    EXPECT_GT(t_sim.rotation_deg, 0.02);

    const auto& r = t.datum_fit.datums;
    ASSERT_EQ(r.size(), 3u);
    EXPECT_EQ(r[0].dof, 3);
    EXPECT_EQ(r[1].dof, 2);
    EXPECT_EQ(r[2].dof, 1);
    EXPECT_GT(r[0].points, cc.a.size() * 8 / 10);  // all but the edges
    EXPECT_LE(r[0].points, cc.a.size());
    EXPECT_NEAR(r[0].rmse, sigma, 0.1 * sigma);
    EXPECT_NEAR(r[1].rmse, sigma, 0.1 * sigma);
    // The tertiary's residual shows its form error: 15 mm tall, 1 degree off, sqrt(sigma^2 + (15 tan 1 deg)^2
    // / 12).
    EXPECT_GT(r[2].rmse, 1.4 * sigma);

    // The residuals at the simultaneous pose, per datum: the primary pays for the compromise.
    const auto at_sim = evaluate_datums(cc.all, datums, t.sim_fit.T_located_nominal, dst);
    ASSERT_EQ(at_sim.size(), 3u);
    partloc::test::note("  at the simultaneous pose: rmse A %.4f B %.4f C %.4f mm\n", at_sim[0].rmse,
                        at_sim[1].rmse, at_sim[2].rmse);
    EXPECT_GT(at_sim[0].rmse, r[0].rmse);
    EXPECT_LT(at_sim[2].rmse, r[2].rmse);
}

TEST(DatumFit, CovarianceMatchesTheScatterOfRepeatedFits) {
    // The covariance the datum fit reports (for the uncertainty) against repeated fits of the same corner
    // with fresh noise: the squared Mahalanobis distance of the error is chi-squared with 6 degrees of
    // freedom, mean 6; the mean of 30 has a standard deviation of 0.63.
    const double spacing = 0.4, sigma = 0.05;
    const Eigen::Isometry3d N = pose_from_origin_euler({-76.2, -12.7, 20.32}, {0, 0, 0});
    const Eigen::Isometry3d T_true = pose_from_origin_euler({-75.4, -12.1, 20.0}, {0.8, 0.3, -0.5});
    std::vector<DatumSurface> datums = {
        {"A", grid_surface(N, {0, 0, 0}, {40, 0, 0}, {0, 30, 0}, 0.25)},
        {"B", grid_surface(N, {0, 0, 0}, {0, 0, 15}, {40, 0, 0}, 0.25)},
        {"C", grid_surface(N, {0, 0, 0}, {0, 30, 0}, {0, 0, 15}, 0.25)},
    };
    DatumFitSettings st;
    st.noise = sigma;
    st.spacing = spacing;
    const Eigen::Isometry3d T_true_ts = N * T_true.inverse();  // merged points -> nominal, the fit's unknown
    const int trials = 30;
    double sum_d2 = 0, sum_t2 = 0, sum_pred_t2 = 0;
    for (int trial = 0; trial < trials; ++trial) {
        std::mt19937 rng(100 + trial);
        const CastCorner cc = cast_corner(T_true, 0.0, spacing, sigma, rng);
        // Start a little off the truth, as after the simultaneous fit.
        const Eigen::Isometry3d start =
            T_true * N.inverse() * pose_from_origin_euler({0.05, -0.03, 0.02}, {0.02, 0.01, -0.02});
        const DatumFit f = fit_datums(cc.all, datums, start, st);
        ASSERT_TRUE(f.valid) << f.reason;
        const Eigen::Isometry3d X = f.T_located_nominal.inverse() * T_true_ts.inverse();
        const Eigen::AngleAxisd aa(X.linear());
        Vector6d delta;
        delta << aa.angle() * aa.axis(), X.translation();
        const Matrix6d cov = sigma * sigma * f.covariance;
        sum_d2 += delta.dot(cov.ldlt().solve(delta));
        sum_t2 += X.translation().squaredNorm();
        sum_pred_t2 += cov.bottomRightCorner<3, 3>().trace();
    }
    const double mean_d2 = sum_d2 / trials;
    partloc::test::note(
        "datum fit over %d noisy corners: mean squared Mahalanobis error %.2f (6 if the covariance is "
        "honest); rms twist translation %.5f mm, predicted %.5f mm\n",
        trials, mean_d2, std::sqrt(sum_t2 / trials), std::sqrt(sum_pred_t2 / trials));
    EXPECT_GT(mean_d2, 4.0);
    EXPECT_LT(mean_d2, 8.5);
}

TEST(DatumFit, TooFewPointsOrNoDatumsIsAReason) {
    const Eigen::Isometry3d N = Eigen::Isometry3d::Identity();
    std::vector<DatumSurface> datums = {
        {"A", grid_surface(N, {0, 0, 0}, {40, 0, 0}, {0, 30, 0}, 0.5)},
        {"B", grid_surface(N, {0, 0, 0}, {0, 0, 15}, {40, 0, 0}, 0.5)},
        {"C", grid_surface(N, {0, 0, 0}, {0, 30, 0}, {0, 0, 15}, 0.5)},
    };
    std::vector<Eigen::Vector3d> floor_only;
    for (int i = 1; i < 80; ++i)
        for (int j = 1; j < 60; ++j) floor_only.emplace_back(0.5 * i, 0.5 * j, 0.0);
    DatumFitSettings st;
    st.noise = 0.05;
    const DatumFit f = fit_datums(floor_only, datums, Eigen::Isometry3d::Identity(), st);
    EXPECT_FALSE(f.valid);
    EXPECT_NE(f.reason.find("datum B: only 0 points"), std::string::npos) << f.reason;
    datums.pop_back();
    const DatumFit g = fit_datums(floor_only, datums, Eigen::Isometry3d::Identity(), st);
    EXPECT_FALSE(g.valid);
    EXPECT_NE(g.reason.find("needs three datums"), std::string::npos) << g.reason;
}

// ---------------------------------------------------------------------------------------------------------
// Virtual cells

namespace {

/// The job's reference surfaces (the three datum faces of the sim) split into datums by their normals:
/// primary the floor, secondary the larger wall, tertiary the other.
std::vector<Datum> datums_of(const sim::SimulatedJob& sj) {
    const auto& mesh = *sj.job.workpiece.reference_surfaces.mesh;
    const Eigen::Matrix3d R = sj.job.workpiece.T_machine_workpiece.linear();
    std::array<std::shared_ptr<open3d::geometry::TriangleMesh>, 3> parts;
    for (auto& p : parts) p = std::make_shared<open3d::geometry::TriangleMesh>();
    for (const auto& t : mesh.triangles_) {
        const Eigen::Vector3d n = (mesh.vertices_[t[1]] - mesh.vertices_[t[0]])
                                      .cross(mesh.vertices_[t[2]] - mesh.vertices_[t[0]])
                                      .normalized();
        for (int k = 0; k < 3; ++k)
            if (std::abs(n.dot(R.col(k))) > 0.999) {
                auto& m = *parts[k];
                const int base = static_cast<int>(m.vertices_.size());
                for (int c = 0; c < 3; ++c) m.vertices_.push_back(mesh.vertices_[t[c]]);
                m.triangles_.emplace_back(base, base + 1, base + 2);
            }
    }
    const int wall = sj.truth.reference_area[0] >= sj.truth.reference_area[1] ? 0 : 1;
    const int order[3] = {2, wall, 1 - wall};
    const char* names[3] = {"A", "B", "C"};
    std::vector<Datum> datums;
    for (int i = 0; i < 3; ++i) {
        Datum d;
        d.name = names[i];
        d.surfaces.file = std::string("models/datum_") + names[i] + ".stl";
        d.surfaces.mesh = parts[static_cast<std::size_t>(order[i])];
        datums.push_back(d);
    }
    return datums;
}

/// The scans' workpiece points at their true registration, merged and thinned as run_job does.
std::vector<Eigen::Vector3d> merged_at_truth(const sim::SimulatedJob& sj) {
    open3d::geometry::PointCloud merged;
    for (std::size_t i = 0; i < sj.job.scans.size(); ++i) {
        const auto& t = sj.truth.scans[i];
        const Eigen::Isometry3d T =
            sj.job.machine.motion(sj.job.workpiece.moves_with, t.axes).inverse() * t.T_machine_scan;
        for (const auto& p : sj.job.scans[i].points->points_) {
            const Eigen::Vector3d q = T * p;
            if (sj.job.workpiece.region->contains(q)) merged.points_.push_back(q);
        }
    }
    auto thin = merged.VoxelDownSample(*sj.job.scanner.point_spacing);
    thin = std::get<0>(thin->RemoveStatisticalOutliers(20, 2.5));
    return thin->points_;
}

Surface samples_of(const open3d::geometry::TriangleMesh& mesh, double spacing) {
    return make_surface(sample_mesh(mesh, spacing), spacing);
}

}  // namespace

class DatumCell : public ::testing::TestWithParam<int> {};

TEST_P(DatumCell, BothFitsLocateTheTrueCornerFromTrulyRegisteredScans) {
    open3d::utility::SetVerbosityLevel(open3d::utility::VerbosityLevel::Error);
    const int seed = GetParam();
    const sim::SimulatedJob sj =
        seed > 0 ? sim::simulate_random_cell(seed) : sim::simulate_paper_test(-seed, 3);
    const std::vector<Eigen::Vector3d> merged = merged_at_truth(sj);
    const double spacing = *sj.job.scanner.point_spacing, noise = *sj.job.scanner.noise;
    const auto& ref_mesh = *sj.job.workpiece.reference_surfaces.mesh;
    const double ref_spacing =
        std::max(spacing, ref_mesh.GetAxisAlignedBoundingBox().GetExtent().norm() / 400.0);
    const Surface reference = samples_of(ref_mesh, ref_spacing);
    std::vector<DatumSurface> datums;
    for (const auto& d : datums_of(sj)) datums.push_back({d.name, samples_of(*d.surfaces.mesh, ref_spacing)});

    WorkpieceFitSettings ws;
    ws.noise = noise;
    ws.spacing = spacing;
    const WorkpieceFit sim = fit_reference_surfaces(merged, reference, ws);
    ASSERT_TRUE(sim.valid) << sim.reason;
    DatumFitSettings ds;
    ds.noise = noise;
    ds.spacing = spacing;
    const DatumFit dat = fit_datums(merged, datums, sim.T_located_nominal, ds);
    ASSERT_TRUE(dat.valid) << dat.reason;
    const Eigen::Isometry3d& N = sj.job.workpiece.T_machine_workpiece;
    const PoseError e_sim = pose_error(sim.T_located_nominal * N, sj.truth.T_machine_workpiece);
    const PoseError e_dat = pose_error(dat.T_located_nominal * N, sj.truth.T_machine_workpiece);
    const PoseError nominal = pose_error(N, sj.truth.T_machine_workpiece);
    // One-sigma origin uncertainty of the datum fit from its covariance (noise^2 times the unit one). The
    // covariance is of a twist [w, v] of T_located_nominal^-1 about the machine origin, which moves the
    // located corner by -R (w x n + v), n the nominal corner: |.|^2 does not depend on R.
    const Eigen::Vector3d n = N.translation();
    Eigen::Matrix3d n_cross;
    n_cross << 0, -n.z(), n.y(), n.z(), 0, -n.x(), -n.y(), n.x(), 0;
    Eigen::Matrix<double, 3, 6> Jo;
    Jo << -n_cross, Eigen::Matrix3d::Identity();
    const Eigen::Matrix3d cov_o = noise * noise * Jo * dat.covariance * Jo.transpose();
    partloc::test::note(
        "%s (seed %d): %zu merged points, nominal off by %.3f mm %.3f deg; simultaneous error %.4f mm "
        "%.5f deg; datums error %.4f mm %.5f deg (1-sigma origin bound %.4f mm)\n",
        sj.truth.scenario.c_str(), seed, merged.size(), nominal.translation, nominal.rotation_deg,
        e_sim.translation, e_sim.rotation_deg, e_dat.translation, e_dat.rotation_deg,
        std::sqrt(cov_o.trace()));
    for (const auto& d : dat.datums)
        partloc::test::note("  datum %s: %zu points, rmse %.4f mm, conditioning %.3f\n", d.name.c_str(),
                            d.points, d.rmse, d.conditioning);
    EXPECT_LT(e_dat.translation, 0.05);
    EXPECT_LT(e_dat.rotation_deg, 0.03);
    EXPECT_LT(e_sim.translation, 0.05);
    EXPECT_LT(e_sim.rotation_deg, 0.03);
    for (const auto& d : dat.datums) {
        EXPECT_GT(d.points, 300u) << d.name;
        // At most the scanner's noise (it is along the line of sight, and the thinning averages points) and
        // not far below it: no datum fitted to the wrong points or offset.
        EXPECT_LT(d.rmse, noise) << d.name;
        EXPECT_GT(d.rmse, 0.4 * noise) << d.name;
    }
}

INSTANTIATE_TEST_SUITE_P(Seeds, DatumCell, ::testing::Values(11, 12, 13, -1, -2));

// ---------------------------------------------------------------------------------------------------------
// The job file and the whole run

TEST(DatumJob, FieldsDefaultsAndErrors) {
    TempFolder f("partloc_test_datums");
    f.write("a.obj", "v 0 0 0\nv 10 0 0\nv 0 10 0\nf 1 2 3\n");
    f.write("b.obj", "v 0 0 0\nv 10 0 0\nv 0 0 10\nf 1 3 2\n");
    f.write("c.xyz", "0 0 0\n0 10 0\n0 0 10\n0 5 5\n");
    f.write("m.xyz", "0 0 0\n1 0 0\n0 1 0\n");
    const std::string head =
        "fiducials: [{name: F, model: m.xyz, pose: {origin: [0, 0, 0]}}]\nscans: [m.xyz]\nworkpiece:\n";
    const std::string datums =
        "  datums: [{name: A, surfaces: a.obj}, {name: B, surfaces: b.obj}, {name: C, surfaces: {file: "
        "c.xyz, units: mm}}]\n";

    // Datums without reference surfaces: the fit defaults to datums, the reference is their union.
    Job job = io::load_job(f.write("job.yaml", head + datums));
    ASSERT_EQ(job.workpiece.datums.size(), 3u);
    EXPECT_EQ(job.workpiece.datums[1].name, "B");
    EXPECT_TRUE(job.workpiece.datums[0].surfaces.mesh);
    EXPECT_TRUE(job.workpiece.datums[2].surfaces.points);
    EXPECT_EQ(job.workpiece.fit, WorkpieceFitMode::Datums);
    ASSERT_TRUE(job.workpiece.reference_surfaces.points);  // a mesh and points: points
    EXPECT_GE(job.workpiece.reference_surfaces.points->points_.size(), 4u + 2 * 100);

    // All meshes: one mesh. fit: simultaneous is honoured.
    job = io::load_job(
        f.write("job.yaml", head + "  datums: [{name: A, surfaces: a.obj}, {name: B, surfaces: b.obj}, "
                                   "{name: C, surfaces: a.obj}]\n  fit: simultaneous\n"));
    ASSERT_TRUE(job.workpiece.reference_surfaces.mesh);
    EXPECT_EQ(job.workpiece.reference_surfaces.mesh->triangles_.size(), 3u);
    EXPECT_EQ(job.workpiece.fit, WorkpieceFitMode::Simultaneous);

    // Given reference surfaces are kept; no datums: simultaneous.
    job = io::load_job(f.write("job.yaml", head + datums + "  reference_surfaces: c.xyz\n"));
    ASSERT_TRUE(job.workpiece.reference_surfaces.points);
    EXPECT_EQ(job.workpiece.reference_surfaces.points->points_.size(), 4u);
    job = io::load_job(f.write("job.yaml", head + "  reference_surfaces: c.xyz\n"));
    EXPECT_EQ(job.workpiece.fit, WorkpieceFitMode::Simultaneous);
    EXPECT_TRUE(job.workpiece.datums.empty());

    expect_job_error(f.write("job.yaml", head + "  reference_surfaces: c.xyz\n  fit: datums\n"),
                     "workpiece.fit: datums needs workpiece.datums");
    expect_job_error(f.write("job.yaml", head + datums + "  fit: best\n"),
                     "workpiece.fit: expected simultaneous or datums, found 'best'");
    expect_job_error(
        f.write("job.yaml", head + "  datums: [{name: A, surfaces: a.obj}, {name: B, surfaces: b.obj}]\n"),
        "workpiece.datums: expected 3 datums (primary, secondary, tertiary), found 2 items");
    expect_job_error(
        f.write("job.yaml", head + "  datums: [{name: A, surfaces: a.obj}, {name: A, surfaces: b.obj}, "
                                   "{name: C, surfaces: a.obj}]\n"),
        "workpiece.datums[1].name: datum name 'A' is already used by workpiece.datums[0]");
    expect_job_error(
        f.write("job.yaml", head + "  datums: [{name: A, surfaces: a.obj}, {name: B, surface: b.obj}, "
                                   "{name: C, surfaces: a.obj}]\n"),
        "workpiece.datums[1].surface: unknown field");
    expect_job_error(f.write("job.yaml", head + "  final_part: a.obj\n"),
                     "workpiece.reference_surfaces: missing");
    try {
        io::load_job(f.write("job.yaml",
                             head + "  datums: [{name: A, surfaces: a.obj}, {name: B, surfaces: nope.stl}, "
                                    "{name: C, surfaces: a.obj}]\n"));
        ADD_FAILURE() << "a missing datum file must be an error";
    } catch (const io::InputError& e) {
        EXPECT_EQ(e.file(), "nope.stl") << e.what();
    }
}

TEST(DatumJob, RunLocatesByTheDatumsAndReportsEach) {
    open3d::utility::SetVerbosityLevel(open3d::utility::VerbosityLevel::Error);
    TempFolder f("partloc_test_datums");
    sim::SimulatedJob sj = sim::simulate_random_cell(12);
    sj.job.workpiece.datums = datums_of(sj);
    sj.job.workpiece.fit = WorkpieceFitMode::Datums;
    io::write_job(f.dir, sj.job);
    const std::string cmd = std::string(PARTLOC_EXE) + " run " + (f.dir / "job.yaml").string() + " --out " +
                            (f.dir / "out").string() + " --cache " + (f.dir / "cache").string() +
                            " > /dev/null 2> " + (f.dir / "stderr.txt").string();
    ASSERT_EQ(std::system(cmd.c_str()), 0);
    std::ifstream in(f.dir / "out" / "result.json");
    const auto j = nlohmann::json::parse(in);
    ASSERT_EQ(j["status"], "located") << j["workpiece"]["message"];
    EXPECT_EQ(j["workpiece"]["fit"], "datums");
    ASSERT_EQ(j["workpiece"]["datums"].size(), 3u);
    for (int i = 0; i < 3; ++i) {
        EXPECT_EQ(j["workpiece"]["datums"][i]["name"], std::string(1, static_cast<char>('A' + i)));
        EXPECT_GT(j["workpiece"]["datums"][i]["points"].get<int>(), 300);
        EXPECT_LT(j["workpiece"]["datums"][i]["rmse"].get<double>(), 0.13);
        EXPECT_GT(j["workpiece"]["datums"][i]["rmse"].get<double>(), 0.05);
    }
    Eigen::Isometry3d located = Eigen::Isometry3d::Identity();
    for (int r = 0; r < 4; ++r)
        for (int c = 0; c < 4; ++c)
            located.matrix()(r, c) = j["workpiece"]["T_machine_workpiece"][r][c].get<double>();
    const PoseError e = pose_error(located, sj.truth.T_machine_workpiece);
    partloc::test::note(
        "partloc run with datums, random cell 12: origin error %.4f mm, rotation error %.5f deg\n",
        e.translation, e.rotation_deg);
    EXPECT_LT(e.translation, 0.1);
    EXPECT_LT(e.rotation_deg, 0.05);
    EXPECT_TRUE(j["probed_poses"].empty());
}

// A scan that one fiducial's fit alone registered is kept only where the part confirms it
// (part_disowns_scan): fitted again on that scan's points alone, from where all the scans locate the part,
// its points must not move along the surfaces' normals by more than five times the noise. A scan that slides
// along a face it alone shows moves no point along a normal and stays; one that shows the part off does not.
TEST(LoneScan, ThePartDisownsAScanThatShowsItOffNotOneThatSlidesAlongItsOnlyFace) {
    const CornerCase cs = corner_case(17);
    const CastCorner& cc = cs.corner;
    const Surface& reference = cs.reference;
    const Eigen::Isometry3d& T_true = cs.T_true;
    const WorkpieceFitSettings& ws = cs.ws;
    const WorkpieceFit located = fit_reference_surfaces(cc.all, reference, ws);
    ASSERT_TRUE(located.valid) << located.reason;
    const auto moved = [&](std::vector<Eigen::Vector3d> pts, const Eigen::Vector3d& along_part) {
        for (auto& p : pts) p += T_true.linear() * along_part;
        return pts;
    };
    const auto disowned = [&](const std::vector<Eigen::Vector3d>& pts, const WorkpieceFit& at) {
        const std::string why = part_disowns_scan(pts, nullptr, at, reference, ws);
        partloc::test::note("  %s\n", why.empty() ? "confirmed" : why.c_str());
        return why;
    };
    // Registered right: confirmed, the corner and the floor alone.
    EXPECT_EQ(disowned(cc.all, located), "");
    EXPECT_EQ(disowned(cc.a, located), "");
    // Slid 1 mm along the floor, all it shows: no point moves along a normal.
    EXPECT_EQ(disowned(moved(cc.a, {1.0, 0.6, 0.0}), located), "");
    // The floor shown 1 mm high, the corner 1 mm off across a wall: the part it shows lies off.
    EXPECT_NE(disowned(moved(cc.a, {0.0, 0.0, 1.0}), located).find("lies"), std::string::npos);
    EXPECT_NE(disowned(moved(cc.all, {1.0, 0.0, 0.0}), located).find("lies"), std::string::npos);
    // Nowhere near the part: unconfirmed.
    EXPECT_NE(disowned(moved(cc.all, {0.0, 0.0, 60.0}), located).find("does not confirm"), std::string::npos);
    // With the part not located by the scans together, the scan's own points must fix it: the corner does,
    // the floor alone does not.
    const WorkpieceFit not_located;
    EXPECT_EQ(disowned(cc.all, not_located), "");
    EXPECT_NE(disowned(cc.a, not_located).find("does not confirm"), std::string::npos);
}
