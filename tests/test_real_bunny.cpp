// Real scans with known answers: the Stanford bunny range scans, with the zippered reconstruction as the
// "fiducial". Each scan must land where bun.conf says, within 1 degree and 2 mm at the bunny.
#include <gtest/gtest.h>
#include <open3d/geometry/BoundingVolume.h>
#include <open3d/io/PointCloudIO.h>
#include <open3d/io/TriangleMeshIO.h>
#include <open3d/utility/Logging.h>

#include <fstream>
#include <map>
#include <sstream>

#include "partloc/pipeline/run.hpp"
#include "test_note.hpp"

using namespace partloc;

namespace {

const std::string kDir = std::string(PARTLOC_DATA_DIR) + "/stanford_bunny/";

// bun.conf: "bmesh FILE tx ty tz qx qy qz qw"; the pose is P = [R(q)^T | t] (the conjugate quaternion,
// data README), p_world = P p_scan.
std::map<std::string, Eigen::Isometry3d> read_conf() {
    std::map<std::string, Eigen::Isometry3d> poses;
    std::ifstream in(kDir + "bun.conf");
    std::string line;
    while (std::getline(in, line)) {
        std::istringstream ss(line);
        std::string tag, file;
        double tx, ty, tz, qx, qy, qz, qw;
        if (!(ss >> tag >> file >> tx >> ty >> tz >> qx >> qy >> qz >> qw) || tag != "bmesh") continue;
        Eigen::Isometry3d P = Eigen::Isometry3d::Identity();
        P.linear() = Eigen::Quaterniond(qw, qx, qy, qz).normalized().toRotationMatrix().transpose();
        P.translation() = Eigen::Vector3d(tx, ty, tz);
        poses[file] = P;
    }
    return poses;
}

}  // namespace

TEST(RealBunny, EveryScanLandsWhereBunConfSays) {
    open3d::utility::SetVerbosityLevel(open3d::utility::VerbosityLevel::Error);
    const auto conf = read_conf();
    auto mesh = std::make_shared<open3d::geometry::TriangleMesh>();
    ASSERT_TRUE(open3d::io::ReadTriangleMesh(kDir + "reconstruction_bun_zipper_res2.ply", *mesh));

    Job job;
    job.units = "m";
    Fiducial f;
    f.name = "bunny";
    f.model.file = "reconstruction_bun_zipper_res2.ply";
    f.model.mesh = mesh;
    job.fiducials.push_back(f);
    job.workpiece.reference_surfaces.mesh = mesh;
    const std::vector<std::string> files{"bun000.ply", "bun045.ply", "bun090.ply", "bun180.ply",
                                         "bun270.ply", "bun315.ply", "top2.ply",   "top3.ply"};
    for (const auto& file : files) {
        auto pc = std::make_shared<open3d::geometry::PointCloud>();
        ASSERT_TRUE(open3d::io::ReadPointCloud(kDir + file, *pc));
        job.scans.push_back({file, pc, {}});
    }
    RunSettings rs;
    rs.build_stock = false;
    const JobResult result = run_job(job, rs);
    const Eigen::Vector3d bunny_centre = mesh->GetAxisAlignedBoundingBox().GetCenter();
    for (std::size_t i = 0; i < files.size(); ++i) {
        const auto& r = result.scans[i];
        SCOPED_TRACE(files[i] + " " + r.reason);
        const Eigen::Isometry3d& P = conf.at(files[i]);
        {
            const auto& f = r.fits[0];
            const Eigen::Isometry3d E = f.T_scan_fiducial * P;  // identity when the fit is right
            partloc::test::note(
                "%s fit: err %.2f deg %.2f mm inl %zu cov %.2f viol %.3f cond %.4f rmse %.3f mm noise %.3f "
                "mm spacing %.3f\n",
                files[i].c_str(), rotation_angle_deg(E.linear()),
                1000 * (E * bunny_centre - bunny_centre).norm(), f.inliers, f.coverage, f.violation,
                f.conditioning, 1000 * f.rmse, 1000 * r.noise, 1000 * r.point_spacing);
        }
        EXPECT_TRUE(r.valid);
        if (!r.valid) continue;
        const Eigen::Isometry3d D = r.T_machine_scan * P.inverse();  // identity when right
        EXPECT_LT(rotation_angle_deg(D.linear()), 1.0);
        EXPECT_LT((D * bunny_centre - bunny_centre).norm(), 0.002);
        partloc::test::note("%s: rotation %.3f deg, at bunny %.3f mm, rmse %.3f mm, coverage %.2f, %.1f s\n",
                            files[i].c_str(), rotation_angle_deg(D.linear()),
                            1000 * (D * bunny_centre - bunny_centre).norm(), 1000 * r.rmse,
                            r.fits[0].coverage, r.seconds);
    }
}
