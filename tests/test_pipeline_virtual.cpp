// The whole pipeline on virtual cells with a known answer: shapes partloc has never seen, scanner noise
// 0.13 mm, clutter from pallet, chuck and trunnion, fiducials whose bottom sits on the pallet (issue 2).
#include <gtest/gtest.h>
#include <open3d/geometry/BoundingVolume.h>
#include <open3d/utility/Logging.h>

#include <algorithm>
#include <cstdio>
#include <random>

#include "partloc/core/icp.hpp"
#include "partloc/pipeline/run.hpp"
#include "partloc/sim/scenario.hpp"
#include "test_note.hpp"

using namespace partloc;

namespace {

// A scan "sees a fiducial" when the fiducial got this many true returns.
constexpr std::size_t kSeenPoints = 4000;

// A registered scan's fit rows say what its status says (issue 27): accepted exactly the fiducials that fix
// it, each with no reason, and every other one rejected with one.
void expect_fits_agree_with_status(const ScanResult& r) {
    std::vector<std::string> accepted;
    for (const auto& f : r.fits) {
        if (f.valid) accepted.push_back(f.fiducial);
        EXPECT_EQ(f.valid, f.reason.empty()) << r.file << " " << f.fiducial << ": " << f.reason;
    }
    std::vector<std::string> fixing = r.fiducials;
    std::sort(accepted.begin(), accepted.end());
    std::sort(fixing.begin(), fixing.end());
    EXPECT_EQ(accepted, fixing) << r.file;
}

void check_job(const sim::SimulatedJob& sj, double max_origin_mm, double max_rotation_deg) {
    RunSettings rs;
    rs.build_stock = false;
    const JobResult result = run_job(sj.job, rs);
    ASSERT_EQ(result.scans.size(), sj.truth.scans.size());
    for (std::size_t i = 0; i < result.scans.size(); ++i) {
        const auto& r = result.scans[i];
        const auto& t = sj.truth.scans[i];
        SCOPED_TRACE(r.file + ": " + r.reason);
        std::size_t seen = 0;
        for (const auto& [name, n] : t.fiducial_points) seen = std::max(seen, n);
        if (seen >= kSeenPoints) EXPECT_TRUE(r.valid) << "a scan that sees a fiducial must be registered";
        for (const auto& f : r.fits) {
            const Eigen::Isometry3d Tf = sj.truth.T_machine_fiducial.at(f.fiducial);
            const Eigen::Isometry3d E = t.T_machine_scan * f.T_scan_fiducial * Tf.inverse();
            const Eigen::Isometry3d W = t.T_machine_scan * f.T_scan_fiducial;
            const Eigen::Vector3d ts = (t.T_machine_scan.inverse() * Tf).translation();
            partloc::test::note("    true in scan at %.1f %.1f %.1f\n", ts.x(), ts.y(), ts.z());
            partloc::test::note(
                "    placed at machine %.1f %.1f %.1f, fiducial z axis -> %.2f %.2f %.2f; true at %.1f %.1f "
                "%.1f\n",
                W.translation().x(), W.translation().y(), W.translation().z(), W.linear()(0, 2),
                W.linear()(1, 2), W.linear()(2, 2), Tf.translation().x(), Tf.translation().y(),
                Tf.translation().z());
            partloc::test::note(
                "  %s %s seen %zu: %s err %.2f deg %.2f mm inl %zu cov %.2f viol %.3f cond %.4f rmse %.3f "
                "%s\n",
                r.file.c_str(), f.fiducial.c_str(),
                t.fiducial_points.count(f.fiducial) ? t.fiducial_points.at(f.fiducial) : 0,
                f.valid ? "ACC" : "rej", rotation_angle_deg(E.linear()), E.translation().norm(), f.inliers,
                f.coverage, f.violation, f.conditioning, f.rmse, f.reason.c_str());
        }
        const Eigen::Vector3d tt = t.T_machine_scan.translation();
        partloc::test::note("  %s: %s true T %.1f %.1f %.1f\n", r.file.c_str(),
                            r.valid ? "REGISTERED" : r.reason.c_str(), tt.x(), tt.y(), tt.z());
        if (!r.valid) continue;
        expect_fits_agree_with_status(r);
        // Registered means registered right: compare at the workpiece's datum (where it matters).
        const Eigen::Vector3d at = sj.truth.T_machine_workpiece.translation();
        const Eigen::Isometry3d D = r.T_machine_scan * t.T_machine_scan.inverse();
        EXPECT_LT((D * at - at).norm(), 0.5) << "scan registered wrongly";
        EXPECT_LT(rotation_angle_deg(D.linear()), 0.2) << "scan registered wrongly";
    }
    ASSERT_TRUE(result.workpiece.valid) << result.workpiece.reason;
    const PoseError e = pose_error(result.workpiece.T_machine_workpiece, sj.truth.T_machine_workpiece);
    partloc::test::note(
        "%s seed %llu: origin error %.4f mm, rotation error %.4f deg, %zu points, rmse %.4f mm, %.1f s\n",
        sj.truth.scenario.c_str(), static_cast<unsigned long long>(sj.truth.seed), e.translation,
        e.rotation_deg, result.workpiece.points, result.workpiece.rmse, result.seconds);
    EXPECT_LT(e.translation, max_origin_mm);
    EXPECT_LT(e.rotation_deg, max_rotation_deg);
    // The reported uncertainty is there and not absurd: the truth within three half-widths of 95 % (the
    // coverage itself is measured over a hundred trials by bench/trials, not by one test).
    const auto& u = result.workpiece.uncertainty;
    ASSERT_TRUE(u.available);
    const Eigen::Vector3d eo =
        result.workpiece.T_machine_workpiece.translation() - sj.truth.T_machine_workpiece.translation();
    for (int k = 0; k < 3; ++k) {
        EXPECT_GT(u.origin(k), 0.0);
        EXPECT_LT(std::abs(eo(k)), 3.0 * u.origin(k)) << "origin component " << k;
    }
}

}  // namespace

class RandomCell : public ::testing::TestWithParam<int> {};

TEST_P(RandomCell, LocatesUnseenWorkpieceWithinFiftyMicrons) {
    open3d::utility::SetVerbosityLevel(open3d::utility::VerbosityLevel::Error);
    check_job(sim::simulate_random_cell(GetParam()), 0.05, 0.05);
}

INSTANTIATE_TEST_SUITE_P(Seeds, RandomCell, ::testing::Values(11, 12, 13));

// Seed 1001's part is squared to the machine and shows small reference faces (about 6,700 samples of
// 0.38 mm on all three). Thinning the merged scans on a voxel grid turned it 0.11 degrees (the voxels'
// choice of points depends on the noise where a face is nearly parallel to their planes); the issue's
// rotation target is 0.03 degrees.
TEST(SmallReferenceFaces, PartSquaredToTheMachineIsLocatedWithinThreeHundredthsOfADegree) {
    open3d::utility::SetVerbosityLevel(open3d::utility::VerbosityLevel::Error);
    check_job(sim::simulate_random_cell(1001), 0.05, 0.03);
}

// A random cell with the fiducials' probed poses disturbed as in bench/trials, run: the result, and how far
// the located part is from the truth (located asserted).
namespace {
struct DisturbedRun {
    JobResult result;
    PoseError error;
};
DisturbedRun run_disturbed(std::uint64_t seed, const RegistrationSettings& registration = {}) {
    sim::SimulatedJob sj = sim::simulate_random_cell(seed);
    sim::disturb_probing(sj.job, seed);
    RunSettings rs;
    rs.build_stock = false;
    rs.config.registration = registration;
    DisturbedRun d{run_job(sj.job, rs), {}};
    EXPECT_TRUE(d.result.workpiece.valid) << d.result.workpiece.reason;
    if (d.result.workpiece.valid)
        d.error = pose_error(d.result.workpiece.T_machine_workpiece, sj.truth.T_machine_workpiece);
    partloc::test::note("seed %d: %.4f mm %.4f deg off\n", static_cast<int>(seed), d.error.translation,
                        d.error.rotation_deg);
    return d;
}
}  // namespace

// Seed 1150: the part sits 1.6 degrees off nominal, but the part's fit from nominal with its widest stage
// first ended 20.5 degrees off, even when it started at the truth (points of faces that are not reference
// surfaces, near them, held it there). The fit now also runs from narrower first stages and keeps the one
// with the most points on the surfaces.
TEST(PartFit, AWideFirstStageThatSlidesOffDoesNotWin) {
    open3d::utility::SetVerbosityLevel(open3d::utility::VerbosityLevel::Error);
    const DisturbedRun d = run_disturbed(1150);
    ASSERT_TRUE(d.result.workpiece.valid);
    EXPECT_LT(d.error.translation, 0.05);
    EXPECT_LT(d.error.rotation_deg, 0.05);
}

// Seed 1143: scan 3 is placed by fiducials B and C seen so that its registration leaves the part uncertain
// by 0.076 mm (1 sigma) along y, against at most 0.009 mm for the other scans; it is 0.21 mm off there, and
// with it the part was located 0.074 mm off. The surfaces the scanner faces hold 1.1 % of its fit along
// that direction: the scan is rejected as held only by surfaces seen edge-on. Without that check it stays
// registered, with a warning, and the part is fitted without it.
TEST(PartFit, AScanWhoseRegistrationIsFarLessCertainIsLeftOutOfIt) {
    open3d::utility::SetVerbosityLevel(open3d::utility::VerbosityLevel::Error);
    {
        const DisturbedRun d = run_disturbed(1143);
        ASSERT_TRUE(d.result.workpiece.valid);
        ASSERT_EQ(d.result.scans.size(), 6u);
        EXPECT_FALSE(d.result.scans[3].valid);
        EXPECT_EQ(d.result.scans[3].reason.rfind("one direction is held only by surfaces seen edge-on", 0),
                  0u)
            << d.result.scans[3].reason;
        EXPECT_LT(d.error.translation, 0.04);
        EXPECT_LT(d.error.rotation_deg, 0.03);
    }
    RegistrationSettings no_edge_check;
    no_edge_check.min_facing_share = 0.0;
    const DisturbedRun d = run_disturbed(1143, no_edge_check);
    ASSERT_TRUE(d.result.workpiece.valid);
    int left_out = 0;
    for (const auto& r : d.result.scans) {
        for (const auto& w : r.warnings) {
            if (w.find("left out of the part's fit") == std::string::npos) continue;
            ++left_out;
            partloc::test::note("  %s: %s\n", r.file.c_str(), w.c_str());
            EXPECT_TRUE(r.valid);
        }
    }
    EXPECT_EQ(left_out, 1);
    // The job's warnings (SPEC "Status with warnings") repeat every scan's, named by the scan.
    std::size_t scan_warnings = 0;
    for (const auto& r : d.result.scans)
        for (const auto& w : r.warnings) {
            ++scan_warnings;
            EXPECT_NE(std::find(d.result.warnings.begin(), d.result.warnings.end(), r.file + ": " + w),
                      d.result.warnings.end());
        }
    // ... and then the final part's (its allowance: the unscanned share of its surface, a shortfall).
    EXPECT_EQ(d.result.warnings.size(), scan_warnings + d.result.machining.warnings.size());
    EXPECT_LT(d.error.translation, 0.04);
    EXPECT_LT(d.error.rotation_deg, 0.03);
}

// merged.ply and the stock hold every registered scan, also one left out of the part's fit: the stock's task
// starts on the first merge and starts again from the written points when they differ (run.cpp). Seed 1143
// run as is, and without the scan that is left out: merged.ply differs (the scans are thinned together to at
// most 150 000 points, so it need not have more points); from the part's points alone it would be the same.
TEST(PartFit, AScanLeftOutOfTheFitIsStillInMergedAndTheStock) {
    open3d::utility::SetVerbosityLevel(open3d::utility::VerbosityLevel::Error);
    sim::SimulatedJob sj = sim::simulate_random_cell(1143);
    sim::disturb_probing(sj.job, 1143);
    RunSettings rs;
    rs.build_stock = true;
    // Scan 3 is held along one direction only by surfaces seen edge-on (above): without that check it is
    // registered, and then left out of the part's fit.
    rs.config.registration.min_facing_share = 0.0;
    const JobResult all = run_job(sj.job, rs);
    ASSERT_TRUE(all.workpiece.valid) << all.workpiece.reason;
    std::size_t left_out = all.scans.size();
    for (std::size_t i = 0; i < all.scans.size(); ++i)
        for (const auto& w : all.scans[i].warnings)
            if (w.find("left out of the part's fit") != std::string::npos) left_out = i;
    ASSERT_LT(left_out, all.scans.size());
    ASSERT_TRUE(all.merged && all.stock);
    EXPECT_GT(all.stock->triangles_.size(), 1000u);
    sj.job.scans.erase(sj.job.scans.begin() + static_cast<std::ptrdiff_t>(left_out));
    const JobResult rest = run_job(sj.job, rs);
    ASSERT_TRUE(rest.workpiece.valid && rest.merged);
    partloc::test::note("merged.ply: %zu points with scan %zu, %zu without\n", all.merged->points_.size(),
                        left_out, rest.merged->points_.size());
    EXPECT_NE(all.merged->points_, rest.merged->points_);
}

TEST(PaperTest, Test2WithTheLargestTiltIsLocated) {
    open3d::utility::SetVerbosityLevel(open3d::utility::VerbosityLevel::Error);
    check_job(sim::simulate_paper_test(2, 5), 0.05, 0.05);
}

// Every fiducial in view counts, and one that moved is named (issue 4). Seed 3's cell has three fiducials,
// and some scans see all three; fiducial C's probed pose is put 0.6 mm off (4.6 noise sigmas), as if it
// had been knocked after probing.
TEST(MovedFiducial, IsNamedAndNoScanIsRegisteredWrongly) {
    open3d::utility::SetVerbosityLevel(open3d::utility::VerbosityLevel::Error);
    sim::SimulatedJob sj = sim::simulate_random_cell(3);
    ASSERT_EQ(sj.job.fiducials.size(), 3u);
    ASSERT_EQ(sj.job.fiducials[2].name, "C");
    sj.job.fiducials[2].T_machine_fiducial.pretranslate(Eigen::Vector3d(0.6, 0.0, 0.0));
    RunSettings rs;
    rs.build_stock = false;
    const JobResult result = run_job(sj.job, rs);
    const Eigen::Vector3d at = sj.truth.T_machine_workpiece.translation();
    int named = 0, registered = 0;
    for (std::size_t i = 0; i < result.scans.size(); ++i) {
        const auto& r = result.scans[i];
        std::string said = r.reason;
        for (const auto& w : r.warnings) said += " " + w;
        partloc::test::note("  %s: %s (scale %.6f +- %.2g) | %s\n", r.file.c_str(),
                            r.valid ? "registered" : "rejected", r.scale, r.scale_sigma, said.c_str());
        if (said.find("C ") != std::string::npos || said.find(" C") != std::string::npos) ++named;
        if (!r.valid) continue;
        ++registered;
        // Registered means registered right, and not by the moved fiducial.
        const Eigen::Isometry3d D = r.T_machine_scan * sj.truth.scans[i].T_machine_scan.inverse();
        EXPECT_LT((D * at - at).norm(), 0.1) << r.file;
        EXPECT_EQ(std::count(r.fiducials.begin(), r.fiducials.end(), "C"), 0) << r.file;
        expect_fits_agree_with_status(r);
    }
    EXPECT_GT(named, 0) << "no scan names the moved fiducial";
    EXPECT_GE(registered, 1);  // safety over recall: scans that cannot tell which fiducial moved are rejected
    ASSERT_TRUE(result.workpiece.valid) << result.workpiece.reason;
    EXPECT_LT(pose_error(result.workpiece.T_machine_workpiece, sj.truth.T_machine_workpiece).translation,
              0.05);
}

// Issue 27's third mistake: fiducial A's probed X typed 0.5 mm off, in seed 3's cell of three fiducials.
// Every scan that names a fiducial as moved names A (it was C's name that the user read), no scan is placed
// by A, and the located pose is within its 95 % interval of the truth, or the scans that A placed are out.
TEST(MisprobedFiducial, TheOneProbedOffIsNamedAndTheIntervalCoversTheTruth) {
    open3d::utility::SetVerbosityLevel(open3d::utility::VerbosityLevel::Error);
    for (const double dx : {0.5, -0.5}) {
        sim::SimulatedJob sj = sim::simulate_random_cell(3);
        ASSERT_EQ(sj.job.fiducials[0].name, "A");
        sj.job.fiducials[0].T_machine_fiducial.pretranslate(Eigen::Vector3d(dx, 0.0, 0.0));
        RunSettings rs;
        rs.build_stock = false;
        const JobResult result = run_job(sj.job, rs);
        int named_a = 0, named_other = 0;
        for (std::size_t i = 0; i < result.scans.size(); ++i) {
            const auto& r = result.scans[i];
            std::string said = r.reason;
            for (const auto& w : r.warnings) said += " " + w;
            partloc::test::note("  dx %g %s: %s | %s\n", dx, r.file.c_str(),
                                r.valid ? "registered" : "rejected", said.c_str());
            for (const char* f : {"A", "B", "C"}) {
                const bool named = said.find(std::string("fiducial ") + f + " ") != std::string::npos;
                if (named) ++(std::string(f) == "A" ? named_a : named_other);
            }
            if (!r.valid) continue;
            EXPECT_EQ(std::count(r.fiducials.begin(), r.fiducials.end(), "A"), 0) << r.file;
            expect_fits_agree_with_status(r);
        }
        EXPECT_GT(named_a, 0) << "dx " << dx;
        EXPECT_EQ(named_other, 0) << "dx " << dx;
        ASSERT_TRUE(result.workpiece.valid) << result.workpiece.reason;
        const auto& w = result.workpiece;
        const Eigen::Vector3d off =
            w.T_machine_workpiece.translation() - sj.truth.T_machine_workpiece.translation();
        ASSERT_TRUE(w.uncertainty.available);
        for (int k = 0; k < 3; ++k)
            EXPECT_LE(std::abs(off[k]), w.uncertainty.origin[k]) << "dx " << dx << " axis " << k;
    }
}

// A scan that sees the part and one fiducial only, where that fiducial was knocked 15 mm and 4 degrees from
// its probed pose: that fiducial's fit alone would place the scan wrongly. The part's points then lie off the
// part that the other scans locate, and the scan must be rejected with that reason, not registered.
TEST(LoneFiducialMoved, ScanItAlonePlacesIsRejected) {
    open3d::utility::SetVerbosityLevel(open3d::utility::VerbosityLevel::Error);
    sim::SimulatedJob sj = sim::simulate_random_cell(3);
    ASSERT_EQ(sj.job.fiducials[0].name, "A");
    // Scan 0 keeps only A's and the part's points.
    const auto& s0 = sj.scans[0];
    auto kept = std::make_shared<open3d::geometry::PointCloud>();
    std::size_t of_a = 0;
    for (std::size_t k = 0; k < s0.points->points_.size(); ++k) {
        const int b = s0.body[k];
        if (b < 0) continue;
        const auto& body = sj.cell.bodies[b];
        if (body.name == "A" || body.kind == sim::BodyKind::Workpiece)
            kept->points_.push_back(s0.points->points_[k]);
        of_a += body.name == "A";
    }
    ASSERT_GT(of_a, 5000u) << "scan 0 must see A well for this test";
    sj.job.scans[0].points = kept;
    // A's probed pose is now 15 mm and 4 degrees from where A is: the job thinks A is elsewhere.
    auto& A = sj.job.fiducials[0];
    const Eigen::Vector3d centre =
        A.T_machine_fiducial * A.model.mesh->GetAxisAlignedBoundingBox().GetCenter();
    Eigen::Isometry3d knock = Eigen::Isometry3d::Identity();
    knock.translate(centre + Eigen::Vector3d(15.0, 0.0, 0.0));
    knock.rotate(Eigen::AngleAxisd(4.0 * M_PI / 180.0, Eigen::Vector3d::UnitZ()));
    knock.translate(-centre);
    A.T_machine_fiducial = knock * A.T_machine_fiducial;
    RunSettings rs;
    rs.build_stock = false;
    const JobResult result = run_job(sj.job, rs);
    for (const auto& r : result.scans) {
        std::string fids;
        for (const auto& f : r.fiducials) fids += " " + f;
        partloc::test::note("  %s: %s%s | %s\n", r.file.c_str(), r.valid ? "registered by" : "rejected",
                            fids.c_str(), r.reason.c_str());
    }
    const auto& r0 = result.scans[0];
    EXPECT_FALSE(r0.valid) << "scan 0 registered by the knocked fiducial alone";
    // Rejected because the part disowns it, or, once the other scans found A moved, without A.
    std::string said = r0.reason;
    for (const auto& w : r0.warnings) said += " " + w;
    EXPECT_TRUE(said.find("A moved") != std::string::npos ||
                said.find("fiducial A left out of this scan") != std::string::npos)
        << said;
    const Eigen::Vector3d at = sj.truth.T_machine_workpiece.translation();
    for (std::size_t i = 0; i < result.scans.size(); ++i) {
        const auto& r = result.scans[i];
        if (!r.valid) continue;
        const Eigen::Isometry3d D = r.T_machine_scan * sj.truth.scans[i].T_machine_scan.inverse();
        EXPECT_LT((D * at - at).norm(), 0.1) << r.file;
    }
    ASSERT_TRUE(result.workpiece.valid) << result.workpiece.reason;
    EXPECT_LT(pose_error(result.workpiece.T_machine_workpiece, sj.truth.T_machine_workpiece).translation,
              0.05);
}

namespace {
// Fiducial A's model mirrored, in a job of scan `scan` alone: the scan is registered right, or rejected with
// `reason` in its message (empty: any reason); the part is never located wrongly.
void check_lone_scan_with_a_mirrored(sim::SimulatedJob sj, std::size_t scan,
                                     const std::string& reason = "the part does not confirm it") {
    ASSERT_EQ(sj.job.fiducials[0].name, "A");
    ASSERT_GT(sj.truth.scans[scan].fiducial_points["A"], 8000u) << "the scan must see A well for this test";
    sj.job.scans = {sj.job.scans[scan]};
    auto mesh = std::make_shared<open3d::geometry::TriangleMesh>(*sj.job.fiducials[0].model.mesh);
    for (auto& v : mesh->vertices_) v.x() = -v.x();
    for (auto& tri : mesh->triangles_) std::swap(tri(1), tri(2));
    sj.job.fiducials[0].model.mesh = mesh;
    RunSettings rs;
    rs.build_stock = false;
    const JobResult result = run_job(sj.job, rs);
    ASSERT_EQ(result.scans.size(), 1u);
    const auto& r0 = result.scans[0];
    partloc::test::note("  %s: %s | %s\n", r0.file.c_str(), r0.valid ? "registered" : "rejected",
                        r0.reason.c_str());
    if (r0.valid) {
        const Eigen::Vector3d at = sj.truth.T_machine_workpiece.translation();
        const Eigen::Isometry3d D = r0.T_machine_scan * sj.truth.scans[scan].T_machine_scan.inverse();
        EXPECT_LT((D * at - at).norm(), 0.1) << "registered wrongly by " << r0.fiducials.front();
    } else {
        EXPECT_NE(r0.reason.find(reason), std::string::npos) << r0.reason;
    }
    EXPECT_FALSE(result.workpiece.valid &&
                 pose_error(result.workpiece.T_machine_workpiece, sj.truth.T_machine_workpiece).translation >
                     0.1);
}
}  // namespace

// A shape close to a fiducial's mirror image (issue 4), in a job of one scan that sees A well and B hardly at
// all. The mirrored model fits A's points turned over (measured: 143 mm and 180 degrees off, passing every
// check of the fit), and with one scan there is no other scan to disagree. The part must then refuse it:
// none of the scan's points, so placed, lies on the reference surfaces.
TEST(MirroredFiducial, LoneScanThePartDoesNotConfirmIsRejected) {
    open3d::utility::SetVerbosityLevel(open3d::utility::VerbosityLevel::Error);
    check_lone_scan_with_a_mirrored(sim::simulate_random_cell(1080), 0);
}

// The same where the scan so placed puts its points on one plane of the reference surfaces. Found in
// bench/trials on seed 1320 (5 % outliers, probing disturbed), registered 224 mm and 178 degrees off with
// 1107 points on one plane, until the part's fit required its points to fix all six degrees of freedom. Seed
// 1355's scan 1 (probing disturbed), placed by B alone, reached that check at 9525799; since 2aeaf0f (every
// 16th point a reference of the global fit) B's mirrored fit is refuted before it, as ambiguous. Either way
// the scan must not be registered wrongly; the one-plane check itself is
// `PartFit.PointsOnOneOrTwoFacesDoNotFixThePart`.
TEST(MirroredFiducial, LoneScanPlacedByAMirrorImageIsNotRegisteredWrongly) {
    open3d::utility::SetVerbosityLevel(open3d::utility::VerbosityLevel::Error);
    sim::SimulatedJob sj = sim::simulate_random_cell(1355);
    sim::disturb_probing(sj.job, 1355);
    check_lone_scan_with_a_mirrored(sj, 1, "");
}

// A scan that two fiducials hold too loosely to place the part within the noise is rejected (0b2fcc2).
// Seed 1430 with A mirrored (probing disturbed, as in bench/trials): scan 3 is held by B and C alone, 0.59 mm
// uncertain at the part (1 sigma), and was registered 0.92 mm off before that check.
TEST(MirroredFiducial, ScanHeldTooLooselyIsRejected) {
    open3d::utility::SetVerbosityLevel(open3d::utility::VerbosityLevel::Error);
    sim::SimulatedJob sj = sim::simulate_random_cell(1430);
    sim::disturb_probing(sj.job, 1430);
    // The mirrored model's fit is held along one direction only by surfaces seen edge-on (0 % from those
    // faced); before that check the part's check rejected it, "the fiducials in view hold it too loosely".
    check_lone_scan_with_a_mirrored(sj, 3, "one direction is held only by surfaces seen edge-on");
}

// Issue 3: results do not depend on the number of threads. Every number the pipeline produces, to the last
// bit: the scans' registrations, the located part, merged.ply's points and the stock.
TEST(Threads, OneAndTwoThreadsGiveTheSameBits) {
    sim::ScenarioOptions o;
    o.a_values = {0.0, 90.0};
    o.scans_per_position = 1;
    const sim::SimulatedJob sj = sim::simulate_random_cell(3, o);
    JobResult r[2];
    for (int t : {1, 2}) {
        RunSettings rs;
        rs.threads = t;
        rs.build_stock = true;
        r[t - 1] = run_job(sj.job, rs);
    }
    ASSERT_EQ(r[0].scans.size(), r[1].scans.size());
    int registered = 0;
    for (std::size_t i = 0; i < r[0].scans.size(); ++i) {
        EXPECT_EQ(r[0].scans[i].valid, r[1].scans[i].valid);
        EXPECT_EQ(r[0].scans[i].reason, r[1].scans[i].reason);
        EXPECT_TRUE(r[0].scans[i].T_machine_scan.matrix() == r[1].scans[i].T_machine_scan.matrix())
            << "scan " << i;
        registered += r[0].scans[i].valid;
    }
    EXPECT_GE(registered, 1);
    ASSERT_TRUE(r[0].workpiece.valid);
    EXPECT_TRUE(r[0].workpiece.T_machine_workpiece.matrix() == r[1].workpiece.T_machine_workpiece.matrix());
    ASSERT_TRUE(r[0].merged && r[1].merged);
    EXPECT_EQ(r[0].merged->points_, r[1].merged->points_);
    EXPECT_EQ(r[0].merged->normals_, r[1].merged->normals_);
    ASSERT_TRUE(r[0].stock && r[1].stock);
    EXPECT_GT(r[0].stock->triangles_.size(), 1000u);
    EXPECT_EQ(r[0].stock->vertices_, r[1].stock->vertices_);
    EXPECT_EQ(r[0].stock->triangles_, r[1].stock->triangles_);
}

// Issue 3: where the first fiducial's fit already has every other fiducial pass its checks where it predicts
// it, the others' own searches are skipped. They place the scans as searching every fiducial does, and the
// skipped fiducial's fit in the result is its judgement at the truth's pose.
TEST(SkippedSearches, PlaceTheScansAsSearchingEveryFiducialDoes) {
    open3d::utility::SetVerbosityLevel(open3d::utility::VerbosityLevel::Error);
    const sim::SimulatedJob sj = sim::simulate_random_cell(3);  // three fiducials
    JobResult r[2];
    for (int every : {0, 1}) {
        RunSettings rs;
        rs.build_stock = false;
        rs.config.registration.search_every_fiducial = every;
        r[every] = run_job(sj.job, rs);
    }
    ASSERT_EQ(r[0].scans.size(), r[1].scans.size());
    const Eigen::Vector3d at = sj.truth.T_machine_workpiece.translation();
    int skipped = 0, unseen = 0, registered = 0;
    for (std::size_t i = 0; i < r[0].scans.size(); ++i) {
        const ScanResult& lazy = r[0].scans[i];
        const ScanResult& every = r[1].scans[i];
        SCOPED_TRACE(lazy.file + ": " + lazy.reason + " / " + every.reason);
        EXPECT_EQ(lazy.valid, every.valid);
        // Every fiducial was searched; a row that says "where the others put it" is one whose own search
        // missed but which the winner's placement explains: accepted, of a registered scan.
        for (const auto& f : every.fits)
            if (!f.searched) EXPECT_TRUE(f.valid && every.valid) << f.fiducial << ": " << f.reason;
        for (const auto& f : lazy.fits) {
            if (f.searched) continue;
            ++skipped;
            // Not searched: judged where the first fiducial put the scanner, which is right; one it does not
            // pass there shows nothing there (out of view or hidden).
            ASSERT_TRUE(lazy.valid);
            if (!f.valid) {
                ++unseen;
                EXPECT_LT(f.inliers, 100u) << f.reason;
                const auto& seen = sj.truth.scans[i].fiducial_points;
                EXPECT_LT(seen.count(f.fiducial) ? seen.at(f.fiducial) : 0, kSeenPoints) << f.fiducial;
                continue;
            }
            const Eigen::Isometry3d Tf = sj.truth.T_machine_fiducial.at(f.fiducial);
            const PoseError e = pose_error(sj.truth.scans[i].T_machine_scan * f.T_scan_fiducial, Tf);
            EXPECT_LT(e.translation, 0.1);
            EXPECT_LT(e.rotation_deg, 0.1);
        }
        if (!lazy.valid || !every.valid) continue;
        ++registered;
        EXPECT_EQ(lazy.fiducials, every.fiducials);
        const Eigen::Isometry3d D = lazy.T_machine_scan * every.T_machine_scan.inverse();
        EXPECT_LT((D * at - at).norm(), 0.005);
        EXPECT_LT(rotation_angle_deg(D.linear()), 0.005);
    }
    partloc::test::note(
        "%d scans registered both ways; %d fiducial searches skipped, %d of them out of view\n", registered,
        skipped, unseen);
    EXPECT_GE(skipped, 1);
    EXPECT_GE(registered, 3);
    ASSERT_TRUE(r[0].workpiece.valid && r[1].workpiece.valid);
    const PoseError e = pose_error(r[0].workpiece.T_machine_workpiece, r[1].workpiece.T_machine_workpiece);
    EXPECT_LT(e.translation, 0.005);
    EXPECT_LT(e.rotation_deg, 0.005);
}
