// The processor's parts on synthetic scenes with a known pose: Poisson-disk model sampling, the global fit
// from any pose (property test over random poses), and a verification that a plane cannot fool.
#include <gtest/gtest.h>
#include <open3d/geometry/BoundingVolume.h>
#include <open3d/geometry/KDTreeFlann.h>

#include <Eigen/Eigenvalues>
#include <random>

#include "partloc/core/icp.hpp"
#include "partloc/core/localize.hpp"
#include "partloc/core/surface.hpp"
#include "partloc/sim/shapes.hpp"
#include "test_note.hpp"

using namespace partloc;

namespace {

// A step block of unique shape (no symmetry), 60 x 40 mm, 30 mm tall with two lower cells.
std::shared_ptr<open3d::geometry::TriangleMesh> step_block() {
    sim::HeightField hf;
    hf.x_edges = {0, 22, 41, 60};
    hf.y_edges = {0, 17, 40};
    hf.top = {30, 30, 30, 30, 12, 21};
    hf.bottom = 0;
    return sim::make_height_field_block(hf);
}

// What a scanner at `eye` (scene frame) sees of `mesh` placed at T: samples facing the eye, with noise.
std::shared_ptr<open3d::geometry::PointCloud> view(const open3d::geometry::TriangleMesh& mesh,
                                                   const Eigen::Isometry3d& T, const Eigen::Vector3d& eye,
                                                   double noise, std::mt19937& rng) {
    auto samples = sample_mesh(mesh, 0.4);
    std::normal_distribution<double> g(0.0, noise);
    auto out = std::make_shared<open3d::geometry::PointCloud>();
    for (std::size_t i = 0; i < samples->points_.size(); ++i) {
        const Eigen::Vector3d p = T * samples->points_[i];
        const Eigen::Vector3d n = T.linear() * samples->normals_[i];
        if (n.dot((eye - p).normalized()) < 0.2) continue;  // back faces and grazing ones return nothing
        out->points_.push_back(p + g(rng) * (p - eye).normalized());
    }
    return out;
}

Eigen::Isometry3d random_pose(std::mt19937& rng) {
    std::uniform_real_distribution<double> u(-1, 1);
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
    T.linear() =
        Eigen::Quaterniond(Eigen::Vector4d(u(rng), u(rng), u(rng), u(rng)).normalized()).toRotationMatrix();
    T.translation() = Eigen::Vector3d(50 * u(rng), 50 * u(rng), 400 + 50 * u(rng));
    return T;
}

}  // namespace

TEST(Sampling, PoissonDiskSamplesHaveTheRequestedSpacingAndOutwardNormals) {
    const auto mesh = step_block();
    const auto cloud = sample_mesh(*mesh, 1.0);
    open3d::geometry::KDTreeFlann tree(*cloud);
    std::vector<double> nn;
    std::vector<int> idx;
    std::vector<double> d2;
    for (const auto& p : cloud->points_) {
        tree.SearchKNN(p, 2, idx, d2);
        nn.push_back(std::sqrt(d2[1]));
    }
    std::sort(nn.begin(), nn.end());
    EXPECT_GE(nn.front(), 0.8 - 1e-9);  // no two samples closer than the disk radius
    EXPECT_NEAR(nn[nn.size() / 2], 0.9, 0.15);
    EXPECT_NEAR(static_cast<double>(cloud->points_.size()), mesh_area(*mesh), 0.2 * mesh_area(*mesh));
    // Outward: a sample moved along its normal leaves the block's bounding box or its lower cells' air.
    const Eigen::Vector3d centre = mesh->GetAxisAlignedBoundingBox().GetCenter();
    int outward = 0;
    for (std::size_t i = 0; i < cloud->points_.size(); ++i)
        outward += cloud->normals_[i].dot(cloud->points_[i] - centre) > 0;
    EXPECT_GT(outward, 0.8 * cloud->points_.size());
}

TEST(Localize, FindsTheBlockFromAnyPoseWithNoInitialGuess) {
    const auto mesh = step_block();
    const PreparedModel model = prepare_model("F", mesh.get(), nullptr, 0.5, 3.0);
    std::mt19937 rng(3);
    for (int trial = 0; trial < 6; ++trial) {
        const Eigen::Isometry3d T = random_pose(rng);
        const Eigen::Vector3d eye(0, 0, 0);
        auto scan = view(*mesh, T, eye, 0.05, rng);
        if (scan->points_.size() < 3000) continue;  // seen edge-on from this pose: nothing to find
        const PreparedScan ps = prepare_scan(*scan, {0.4, 0.05}, 3.0, eye);
        const FiducialFit fit = localize_model(ps, model, {});
        SCOPED_TRACE("trial " + std::to_string(trial) + ": " + fit.reason);
        // Seen from one side, a block may show only one or two faces; then it must say so, not guess.
        if (!fit.valid) {
            EXPECT_FALSE(fit.reason.empty());
            continue;
        }
        const PoseError e = pose_error(fit.T_scan_fiducial, T);
        partloc::test::note("trial %d: %.4f mm %.4f deg, conditioning %.4f, %zu points\n", trial,
                            e.translation, e.rotation_deg, fit.conditioning, fit.inliers);
        // Where the view fixes every direction well the fit is exact to the noise; where one direction is
        // held only by a narrow face (low conditioning) edge effects leave up to about 0.1 mm along it.
        const bool well_seen = fit.conditioning > 0.02;
        EXPECT_LT(e.translation, well_seen ? 0.01 : 0.15);
        EXPECT_LT(e.rotation_deg, well_seen ? 0.01 : 0.05);
    }
}

TEST(Localize, APlaneAloneIsNeverAFiducial) {
    const auto mesh = step_block();
    const PreparedModel model = prepare_model("F", mesh.get(), nullptr, 0.5, 3.0);
    open3d::geometry::TriangleMesh plate = *open3d::geometry::TriangleMesh::CreateBox(160, 160, 1);
    plate.Translate(Eigen::Vector3d(-80, -80, -401));
    std::mt19937 rng(5);
    Eigen::Isometry3d flip = Eigen::Isometry3d::Identity();
    flip.linear() = Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitX()).toRotationMatrix();  // face the eye
    auto scan = view(plate, flip, Eigen::Vector3d::Zero(), 0.05, rng);
    ASSERT_GT(scan->points_.size(), 50000u);
    const PreparedScan ps = prepare_scan(*scan, {0.4, 0.05}, 3.0, Eigen::Vector3d::Zero());
    const FiducialFit fit = localize_model(ps, model, {});
    EXPECT_FALSE(fit.valid);
    EXPECT_FALSE(fit.reason.empty());
}

// Issue 25, slid fits: a block seen as a broad top and two narrow sides that hold its weakest direction.
// Moved along that direction by 1.5 mm, the top still fits (it is parallel to the motion) and the narrow
// sides are too small a share of the view for the overall checks, which pass it; the scan contradicts the
// very faces that fix that direction, and the per-direction test must say so. At the true pose those faces
// are observed, and the fit from there is accepted.
TEST(Localize, APoseSlidAlongItsLeastHeldDirectionIsRefutedByTheFacesThatHoldIt) {
    const auto mesh = open3d::geometry::TriangleMesh::CreateBox(60, 40, 8);
    mesh->ComputeTriangleNormals();
    const PreparedModel model = prepare_model("F", mesh.get(), nullptr, 0.5, 3.0);
    std::mt19937 rng(7);
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
    // The eye at the origin looks down -z' onto the top; the block turned so that both narrow sides face it.
    T.linear() = (Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitX()) *
                  Eigen::AngleAxisd(0.35, Eigen::Vector3d::UnitY()) *
                  Eigen::AngleAxisd(-0.3, Eigen::Vector3d::UnitX()))
                     .toRotationMatrix();
    T.translation() = Eigen::Vector3d(-30, -20, 400);
    const Eigen::Vector3d eye(0, 0, 0);
    const auto scan = view(*mesh, T, eye, 0.05, rng);
    ASSERT_GT(scan->points_.size(), 5000u);
    const PreparedScan ps = prepare_scan(*scan, {0.4, 0.05}, 3.0, eye);
    const LocalizeSettings st;
    const FiducialFit at_truth = evaluate_model(ps, model, T, st);
    ASSERT_TRUE(at_truth.valid) << at_truth.reason;
    EXPECT_EQ(slide_refutation(at_truth, st), "");
    EXPECT_GT(at_truth.weakest_observed, 10u);
    const auto fits = fit_candidates(ps, model, st, {PoseCandidate{T, 1.0}});
    ASSERT_FALSE(fits.empty());
    EXPECT_TRUE(fits.front().valid) << fits.front().reason;
    EXPECT_LT(pose_error(fits.front().T_scan_fiducial, T).translation, 0.05);
    // The direction the true pose's inliers hold least, as the slide restarts take it.
    const double L = 0.5 * model.dense.diameter;
    const Matrix6d S = centred_scaled(model.dense.center, L);
    const Eigen::SelfAdjointEigenSolver<Matrix6d> es(S * at_truth.JtJ * S.transpose());
    const Vector6d weakest = es.eigenvectors().col(0);
    for (const double sign : {1.0, -1.0}) {
        const Eigen::Isometry3d slid =
            (motion_about(sign * 1.5 * weakest, model.dense.center, L) * T.inverse()).inverse();
        const FiducialFit f = evaluate_model(ps, model, slid, st);
        SCOPED_TRACE(sign);
        EXPECT_TRUE(f.valid) << f.reason;  // every other check passes it: the defect this test closes
        EXPECT_GE(f.weakest_against, st.min_weakest_against);
        EXPECT_NE(slide_refutation(f, st).find("least held direction"), std::string::npos);
    }
}
