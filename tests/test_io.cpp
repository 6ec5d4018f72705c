// The I/O layer: readers on every real cloud and mesh in ../shared/data/real (counts against the files'
// own headers, known coordinates, a known transform), bad input of every kind, writers round trip, the
// job loader and result.json.
#include <gtest/gtest.h>
#include <open3d/geometry/KDTreeFlann.h>
#include <unistd.h>

#include <atomic>
#include <cmath>
#include <cstring>
#include <fstream>
#include <functional>
#include <nlohmann/json.hpp>
#include <set>
#include <sstream>

#include "partloc/core/geometry.hpp"
#include "partloc/io/cloud_io.hpp"
#include "partloc/io/job_io.hpp"
#include "partloc/io/report_html.hpp"
#include "partloc/io/result_io.hpp"
#include "test_util.hpp"

using namespace partloc;
using namespace partloc::test;
using namespace partloc::io;
namespace fs = std::filesystem;

namespace {

fs::path data(const std::string& rel) { return fs::path(PARTLOC_DATA_DIR) / rel; }

/// The count a file's own header gives after `keyword` ("element vertex", "element face", "POINTS"), read
/// here independently of the readers under test.
std::size_t header_count(const fs::path& p, const std::string& keyword) {
    const std::string head = slurp(p).substr(0, 8192);
    const std::size_t at = head.find("\n" + keyword + " ");
    if (at == std::string::npos) return 0;
    return std::stoul(head.substr(at + keyword.size() + 2));
}

class TempDir {
  public:
    TempDir() {
        static std::atomic<int> n{0};
        path_ = fs::temp_directory_path() /
                ("partloc_test_io_" + std::to_string(::getpid()) + "_" + std::to_string(n++));
        fs::remove_all(path_);
        fs::create_directories(path_);
    }
    ~TempDir() {
        std::error_code ec;
        fs::remove_all(path_, ec);
    }
    const fs::path& path() const { return path_; }
    fs::path operator/(const std::string& rel) const { return path_ / rel; }

  private:
    fs::path path_;
};

/// Runs `f`, expects an InputError naming `file` whose message holds `phrase`.
void expect_input_error(const std::function<void()>& f, const std::string& file, const std::string& phrase) {
    try {
        f();
        ADD_FAILURE() << "no InputError; expected one naming " << file << " with '" << phrase << "'";
    } catch (const InputError& e) {
        EXPECT_EQ(e.file(), file) << e.what();
        EXPECT_NE(std::string(e.what()).find(phrase), std::string::npos) << "message: " << e.what();
        EXPECT_EQ(std::string(e.what()).find('\n'), std::string::npos) << "not one line: " << e.what();
        EXPECT_EQ(std::string(e.what()).rfind(file + ": ", 0), 0u) << e.what();
    } catch (const std::exception& e) {
        ADD_FAILURE() << "expected InputError, got " << typeid(e).name() << ": " << e.what();
    }
}

/// Median distance from every `step`-th point of `source`, moved by T, to its nearest point in `target`.
double median_nearest_distance(const open3d::geometry::PointCloud& source,
                               const open3d::geometry::PointCloud& target, const Eigen::Isometry3d& T,
                               std::size_t step) {
    open3d::geometry::KDTreeFlann tree(target);
    std::vector<double> d;
    std::vector<int> index(1);
    std::vector<double> d2(1);
    for (std::size_t i = 0; i < source.points_.size(); i += step) {
        tree.SearchKNN(Eigen::Vector3d(T * source.points_[i]), 1, index, d2);
        d.push_back(std::sqrt(d2[0]));
    }
    std::nth_element(d.begin(), d.begin() + d.size() / 2, d.end());
    return d[d.size() / 2];
}

void expect_near(const Eigen::Vector3d& a, const Eigen::Vector3d& b, double tol) {
    EXPECT_LE((a - b).norm(), tol) << "got " << a.transpose() << ", expected " << b.transpose();
}

}  // namespace

// ---------------------------------------------------------------------------------------------------------
// Real clouds

TEST(ReadRealClouds, StanfordBunnyScansSkipTheRangeGridElement) {
    for (const char* name : {"bun000", "bun045", "bun090", "bun180", "bun270", "bun315", "top2", "top3"}) {
        const fs::path p = data(std::string("stanford_bunny/") + name + ".ply");
        const auto cloud = read_point_cloud(p, p.filename().string());
        const std::size_t expected = header_count(p, "element vertex");
        ASSERT_GT(expected, 30000u) << name;
        EXPECT_EQ(cloud->points_.size(), expected) << name;
        EXPECT_FALSE(cloud->HasNormals());
        // The bunny is about 15 cm across, in metres.
        const Eigen::Vector3d size = cloud->GetMaxBound() - cloud->GetMinBound();
        EXPECT_GT(size.maxCoeff(), 0.1) << name;
        EXPECT_LT(size.maxCoeff(), 0.25) << name;
    }
    const auto bun000 = read_point_cloud(data("stanford_bunny/bun000.ply"), "bun000.ply");
    expect_near(bun000->points_.front(), {-0.06325, 0.0359793, 0.0420873}, 1e-7);
    expect_near(bun000->points_.back(), {-0.018, 0.18794, -0.0197253}, 1e-7);
}

TEST(ReadRealClouds, UnitsScaleMultipliesCoordinates) {
    const auto mm = read_point_cloud(data("stanford_bunny/bun000.ply"), "bun000.ply", 1000.0);
    expect_near(mm->points_.front(), {-63.25, 35.9793, 42.0873}, 1e-4);
    EXPECT_THROW(read_point_cloud(data("stanford_bunny/bun000.ply"), "bun000.ply", 0.0),
                 std::invalid_argument);
}

TEST(ReadRealClouds, PcdAsciiBinaryAndCompressed) {
    for (const char* name :
         {"bun0", "bun01", "bun02", "bun03", "bun4", "bunny", "milk", "milk_color", "noisy_slice_displaced",
          "office1_keypoints", "office2_keypoints", "sac_plane_test"}) {
        const fs::path p = data(std::string("pcl_test/") + name + ".pcd");
        const auto cloud = read_point_cloud(p, name);
        EXPECT_EQ(cloud->points_.size(), header_count(p, "POINTS")) << name;
    }
    // ascii with normals: the first line of data, and unit normals kept.
    const auto bun0 = read_point_cloud(data("pcl_test/bun0.pcd"), "bun0.pcd");
    ASSERT_EQ(bun0->points_.size(), 397u);
    ASSERT_TRUE(bun0->HasNormals());
    expect_near(bun0->points_[0], {0.0054215998, 0.11349, 0.040748999}, 1e-8);
    expect_near(bun0->normals_[0], {-0.16884723, -0.45159745, -0.87609947}, 1e-7);
    // binary_compressed (LZF) and binary: the known first points; every point finite and in a room.
    const auto milk = read_point_cloud(data("pcl_test/milk.pcd"), "milk.pcd");
    EXPECT_EQ(milk->points_.size(), 13704u);
    expect_near(milk->points_[0], {-0.131608, -0.209543, 0.772}, 1e-5);
    EXPECT_LT((milk->GetMaxBound() - milk->GetMinBound()).maxCoeff(), 1.0);
    const auto office = read_point_cloud(data("pcl_test/office1_keypoints.pcd"), "office1_keypoints.pcd");
    EXPECT_EQ(office->points_.size(), 1318u);
    expect_near(office->points_[0], {3.64863, 4.24565, 0.459566}, 1e-4);
}

TEST(ReadRealClouds, SmallGicpBinaryPlyWithExtraFieldMatchesKnownTransform) {
    const auto source = read_point_cloud(data("small_gicp/source.ply"), "source.ply");
    const auto target = read_point_cloud(data("small_gicp/target.ply"), "target.ply");
    EXPECT_EQ(source->points_.size(), 69792u);
    EXPECT_EQ(target->points_.size(), 69088u);
    expect_near(source->points_[0], {0.00404511, 2.57519, -1.52722}, 1e-5);

    // The known transform maps source to target; its inverse does not. (Nearest-neighbour distances between
    // two lidar sweeps are dominated by the ring pattern, so the bunny test below is the sharp one.)
    Eigen::Matrix4d M;
    std::istringstream in(slurp(data("small_gicp/T_target_source.txt")));
    for (int i = 0; i < 16; ++i) in >> M(i / 4, i % 4);
    const Eigen::Isometry3d T_target_source(M);
    EXPECT_LT(median_nearest_distance(*source, *target, T_target_source, 20),
              0.6 * median_nearest_distance(*source, *target, T_target_source.inverse(), 20));
}

TEST(ReadRealClouds, BunnyScansLineUpUnderBunConf) {
    // bun.conf: "bmesh bun045.ply tx ty tz qx qy qz qw"; the scan's pose is [R(q)^T | t] (README trap), and
    // bun000's is the identity, so T_bun000_bun045 = [R(q)^T | t].
    const auto bun000 = read_point_cloud(data("stanford_bunny/bun000.ply"), "bun000.ply");
    const auto bun045 = read_point_cloud(data("stanford_bunny/bun045.ply"), "bun045.ply");
    const Eigen::Quaterniond q(0.955586, 0.00548449, -0.294635, -0.0038555);  // w, x, y, z
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
    T.translation() = Eigen::Vector3d(-0.0520211, -0.000383981, -0.0109223);
    T.linear() = q.toRotationMatrix().transpose();
    const double aligned = median_nearest_distance(*bun045, *bun000, T, 20);
    EXPECT_LT(aligned, 0.0008);         // the scanner's own floor is 0.3-0.5 mm
    T.linear() = q.toRotationMatrix();  // the trap: almost nothing lines up
    EXPECT_GT(median_nearest_distance(*bun045, *bun000, T, 20), 5 * aligned);
}

TEST(ReadRealClouds, SickScanAsciiPlyWithIntensity) {
    const fs::path p = data("sick_housing/data.ply");
    const auto cloud = read_point_cloud(p, "data.ply");
    EXPECT_EQ(cloud->points_.size(), 24397u);
    expect_near(cloud->points_[0], {696.09, -445.58, 209.45}, 1e-3);
}

TEST(ReadRealClouds, CsvWithAndWithoutHeader) {
    const auto with = read_point_cloud(data("libpointmatcher/car_cloud400.csv"), "car_cloud400.csv");
    EXPECT_EQ(with->points_.size(), 24989u);  // 24990 lines, one of them the header
    ASSERT_TRUE(with->HasNormals());
    expect_near(with->points_.front(), {-3.5376, 0.639553, -1.37678}, 1e-9);
    expect_near(with->normals_.front(), {-0.060181, 0.173729, 0.982953}, 1e-9);
    expect_near(with->points_.back(), {-0.0559087, 1.29374, 6.64353}, 1e-9);

    const auto without = read_point_cloud(data("libpointmatcher/car_cloud401.csv"), "car_cloud401.csv");
    EXPECT_EQ(without->points_.size(), 25193u);
    EXPECT_FALSE(without->HasNormals());
    expect_near(without->points_.front(), {2.6247663, 0.052711742, -1.0169336}, 1e-9);
}

TEST(ReadRealClouds, LegacyVtkPoints) {
    for (const char* name : {"cloud.00000.vtk", "cloud.00001.vtk", "cloud.00002.vtk"}) {
        const fs::path p = data(std::string("libpointmatcher/") + name);
        EXPECT_EQ(read_point_cloud(p, name)->points_.size(), header_count(p, "POINTS")) << name;
    }
    const auto c = read_point_cloud(data("libpointmatcher/cloud.00000.vtk"), "cloud.00000.vtk");
    expect_near(c->points_.front(), {-3.79521, 0.0131325, -0.95763}, 1e-9);
}

// ---------------------------------------------------------------------------------------------------------
// Real meshes

TEST(ReadRealMeshes, BunnyReconstructionsAndSickHousing) {
    for (const char* name : {"reconstruction_bun_zipper_res2.ply", "reconstruction_bun_zipper_res3.ply",
                             "reconstruction_bun_zipper_res4.ply"}) {
        const fs::path p = data(std::string("stanford_bunny/") + name);
        const auto mesh = read_mesh(p, name);
        EXPECT_EQ(mesh->vertices_.size(), header_count(p, "element vertex")) << name;
        EXPECT_EQ(mesh->triangles_.size(), header_count(p, "element face")) << name;
        EXPECT_EQ(mesh->triangle_normals_.size(), mesh->triangles_.size());
        EXPECT_EQ(mesh->vertex_normals_.size(), mesh->vertices_.size());
    }
    const auto housing = read_mesh(data("sick_housing/V2D63xModel.ply"), "V2D63xModel.ply");
    EXPECT_EQ(housing->vertices_.size(), 77861u);
    EXPECT_EQ(housing->triangles_.size(), 154456u);
    expect_near(housing->GetMinBound(), {40.0102, 14.7379, 0.0478802}, 1e-3);
    expect_near(housing->GetMaxBound(), {86.2845, 77.8379, 113.226}, 1e-3);

    const auto cube = read_mesh(data("pcl_test/cube.ply"), "cube.ply");
    EXPECT_EQ(cube->triangles_.size(), 12u);
    expect_near(cube->GetMinBound(), {-1, -1, -1}, 1e-12);
    expect_near(cube->GetMaxBound(), {1, 1, 1}, 1e-12);
    EXPECT_NEAR(cube->GetSurfaceArea(), 24.0, 1e-9);
}

TEST(ReadRealMeshes, ReadModelIsAMeshWhenTheFileHasFaces) {
    const ModelSource mesh =
        read_model(data("stanford_bunny/reconstruction_bun_zipper_res4.ply"), "res4.ply", 1000);
    ASSERT_TRUE(mesh.mesh);
    EXPECT_FALSE(mesh.points);
    EXPECT_EQ(mesh.file, "res4.ply");
    const ModelSource points = read_model(data("stanford_bunny/bun000.ply"), "bun000.ply");
    ASSERT_TRUE(points.points);
    EXPECT_FALSE(points.mesh);
    EXPECT_EQ(points.points->points_.size(), 40256u);
    expect_input_error([] { read_mesh(data("stanford_bunny/bun000.ply"), "bun000.ply"); }, "bun000.ply",
                       "no faces");
}

// ---------------------------------------------------------------------------------------------------------
// Bad input

TEST(ReadBadInput, MissingFolderEmptyUnknownType) {
    TempDir dir;
    expect_input_error([&] { read_point_cloud(dir / "nope.ply", "scans/nope.ply"); }, "scans/nope.ply",
                       "no such file");
    fs::create_directories(dir / "adir.ply");
    expect_input_error([&] { read_point_cloud(dir / "adir.ply", "adir.ply"); }, "adir.ply", "folder");
    for (const char* name : {"empty.ply", "empty.pcd", "empty.xyz", "empty.csv", "empty.stl", "empty.obj"}) {
        spit(dir / name, "");
        expect_input_error([&] { read_point_cloud(dir / name, name); }, name, "empty");
    }
    spit(dir / "scan.las", "whatever");
    expect_input_error([&] { read_point_cloud(dir / "scan.las", "scan.las"); }, "scan.las",
                       "unknown file type");
}

TEST(ReadBadInput, TruncatedFilesAreReportedNotPartial) {
    TempDir dir;
    const std::string ply = slurp(data("small_gicp/source.ply"));
    const std::size_t header = ply.find("end_header\n") + 11;
    const std::size_t vertex_bytes = 16;  // float x y z scalar_intensity
    spit(dir / "cut.ply", ply.substr(0, header + 1203 * vertex_bytes + 7));
    expect_input_error([&] { read_point_cloud(dir / "cut.ply", "scans/scan_01.ply"); }, "scans/scan_01.ply",
                       "file is truncated (expected 69792 vertices, found 1203)");

    const std::string ascii = slurp(data("stanford_bunny/bun000.ply"));
    spit(dir / "cut_ascii.ply", ascii.substr(0, ascii.size() / 3));
    expect_input_error([&] { read_point_cloud(dir / "cut_ascii.ply", "cut_ascii.ply"); }, "cut_ascii.ply",
                       "file is truncated (expected 40256 vertices");
    // Cut inside the range_grid that follows the vertices: still a damaged file.
    spit(dir / "cut_grid.ply", ascii.substr(0, ascii.size() - 1000));
    expect_input_error([&] { read_point_cloud(dir / "cut_grid.ply", "cut_grid.ply"); }, "cut_grid.ply",
                       "'range_grid' elements");

    const std::string mesh = slurp(data("sick_housing/V2D63xModel.ply"));
    spit(dir / "cut_mesh.ply", mesh.substr(0, mesh.size() / 2));
    expect_input_error([&] { read_mesh(dir / "cut_mesh.ply", "cut_mesh.ply"); }, "cut_mesh.ply",
                       "file is truncated (expected 154456 faces");

    const std::string pcd_bin = slurp(data("pcl_test/office1_keypoints.pcd"));
    spit(dir / "cut.pcd", pcd_bin.substr(0, pcd_bin.size() / 2));
    expect_input_error([&] { read_point_cloud(dir / "cut.pcd", "cut.pcd"); }, "cut.pcd",
                       "file is truncated (expected 1318 points");
    const std::string pcd_lzf = slurp(data("pcl_test/milk.pcd"));
    // PCL pads the compressed block (milk.pcd carries ~3.9 kB after it), so cut well into the data.
    spit(dir / "cut_lzf.pcd", pcd_lzf.substr(0, pcd_lzf.size() / 2));
    expect_input_error([&] { read_point_cloud(dir / "cut_lzf.pcd", "cut_lzf.pcd"); }, "cut_lzf.pcd",
                       "truncated");
    const std::string pcd_ascii = slurp(data("pcl_test/bun0.pcd"));
    spit(dir / "cut_ascii.pcd", pcd_ascii.substr(0, pcd_ascii.size() / 2));
    expect_input_error([&] { read_point_cloud(dir / "cut_ascii.pcd", "cut_ascii.pcd"); }, "cut_ascii.pcd",
                       "file is truncated (expected 397 points");
}

TEST(ReadBadInput, NanOnlyGarbageAndMalformed) {
    TempDir dir;
    spit(dir / "nan.ply",
         "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
         "end_header\nnan nan nan\nnan 1 2\ninf 0 0\n");
    expect_input_error([&] { read_point_cloud(dir / "nan.ply", "nan.ply"); }, "nan.ply", "no finite points");
    spit(dir / "nan.xyz", "nan nan nan\nnan nan nan\n");
    expect_input_error([&] { read_point_cloud(dir / "nan.xyz", "nan.xyz"); }, "nan.xyz", "no finite points");
    spit(dir / "zero.ply",
         "ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\nproperty float "
         "z\nend_header\n");
    expect_input_error([&] { read_point_cloud(dir / "zero.ply", "zero.ply"); }, "zero.ply", "no points");

    std::string noise(3000, '\0');
    for (std::size_t i = 0; i < noise.size(); ++i) noise[i] = static_cast<char>((i * 7919 + 13) % 251);
    for (const char* name :
         {"garbage.ply", "garbage.pcd", "garbage.xyz", "garbage.stl", "garbage.obj", "garbage.vtk"}) {
        spit(dir / name, noise);
        expect_input_error([&] { read_point_cloud(dir / name, name); }, name, "");
    }
    spit(dir / "words.xyz", "hello world\nthis is not a cloud\n");
    expect_input_error([&] { read_point_cloud(dir / "words.xyz", "words.xyz"); }, "words.xyz",
                       "no x, y and z");
    spit(dir / "badtok.ply",
         "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\n"
         "end_header\n1 2 3\n4 abc 6\n");
    expect_input_error([&] { read_point_cloud(dir / "badtok.ply", "badtok.ply"); }, "badtok.ply",
                       "line 9: expected a number for 'y', found 'abc'");
    spit(dir / "ragged.csv", "x,y,z\n1,2,3\n4,5\n");
    expect_input_error([&] { read_point_cloud(dir / "ragged.csv", "ragged.csv"); }, "ragged.csv",
                       "line 3: expected 3 columns, found 2");
    spit(dir / "word.xyz", "1 2 3\n4 five 6\n");
    expect_input_error([&] { read_point_cloud(dir / "word.xyz", "word.xyz"); }, "word.xyz",
                       "line 2: column 2: 'five' is not a number");
    spit(
        dir / "badface.ply",
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
        "element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n");
    expect_input_error([&] { read_mesh(dir / "badface.ply", "badface.ply"); }, "badface.ply", "vertex 7");
    spit(dir / "badface.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n");
    expect_input_error([&] { read_mesh(dir / "badface.obj", "badface.obj"); }, "badface.obj", "line 4");
    spit(dir / "short.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\n");
    expect_input_error([&] { read_mesh(dir / "short.obj", "short.obj"); }, "short.obj", "at least 3");
    spit(dir / "cut.stl", "solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\n");
    expect_input_error([&] { read_mesh(dir / "cut.stl", "cut.stl"); }, "cut.stl", "truncated");
    spit(dir / "nanmesh.stl",
         "solid x\nfacet normal 0 0 1\nouter loop\nvertex nan 0 0\nvertex 1 0 0\nvertex 0 1 "
         "0\nendloop\nendfacet\n"
         "endsolid x\n");
    expect_input_error([&] { read_mesh(dir / "nanmesh.stl", "nanmesh.stl"); }, "nanmesh.stl", "NaN");
}

TEST(ReadBadInput, NonFinitePointsAreDroppedTheRestKept) {
    TempDir dir;
    spit(dir / "some.ply",
         "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
         "end_header\n1 2 3\nnan 0 0\n4 5 6\n0 inf 0\n");
    const auto cloud = read_point_cloud(dir / "some.ply", "some.ply");
    ASSERT_EQ(cloud->points_.size(), 2u);
    expect_near(cloud->points_[1], {4, 5, 6}, 0);
}

TEST(ReadBadInput, ReadersNeverPrint) {
    TempDir dir;
    // A compressed block of the right size whose content is not LZF: Open3D's decoder fails and logs.
    std::string milk = slurp(data("pcl_test/milk.pcd"));
    ASSERT_NE(milk.find("DATA binary_compressed\n"), std::string::npos) << "no real data at " << data("");
    const std::size_t block = milk.find("DATA binary_compressed\n") + 23 + 8;
    for (std::size_t i = block; i < block + 2000; ++i) milk[i] = static_cast<char>(0xff);
    spit(dir / "corrupt.pcd", milk);
    const std::string ply = slurp(data("small_gicp/source.ply"));
    ASSERT_FALSE(ply.empty()) << "no real data at " << data("");
    spit(dir / "cut.ply", ply.substr(0, ply.size() / 2));
    testing::internal::CaptureStdout();
    testing::internal::CaptureStderr();
    EXPECT_THROW(read_point_cloud(dir / "corrupt.pcd", "corrupt.pcd"), InputError);
    EXPECT_THROW(read_point_cloud(dir / "cut.ply", "cut.ply"), InputError);
    EXPECT_THROW(read_mesh(dir / "cut.ply", "cut.ply"), InputError);
    EXPECT_THROW(read_point_cloud(dir / "missing.stl", "missing.stl"), InputError);
    const std::string out = testing::internal::GetCapturedStdout();
    const std::string err = testing::internal::GetCapturedStderr();
    EXPECT_EQ(out, "");
    EXPECT_EQ(err, "");
}

TEST(ReadFormats, BigEndianPlyAndBinaryPcdWithNaNRows) {
    TempDir dir;
    // Big-endian binary PLY, double coordinates, an unused uchar property between them.
    std::string ply =
        "ply\nformat binary_big_endian 1.0\nelement vertex 2\nproperty double x\nproperty uchar flag\n"
        "property double y\nproperty double z\nend_header\n";
    const auto put_be = [&](double v) {
        unsigned char b[8];
        std::memcpy(b, &v, 8);
        for (int i = 7; i >= 0; --i) ply.push_back(static_cast<char>(b[i]));
    };
    for (const Eigen::Vector3d& p : {Eigen::Vector3d(1.5, -2.25, 1e3), Eigen::Vector3d(-7, 0.125, 3)}) {
        put_be(p.x());
        ply.push_back(7);
        put_be(p.y());
        put_be(p.z());
    }
    spit(dir / "be.ply", ply);
    const auto be = read_point_cloud(dir / "be.ply", "be.ply");
    ASSERT_EQ(be->points_.size(), 2u);
    expect_near(be->points_[0], {1.5, -2.25, 1e3}, 0);
    expect_near(be->points_[1], {-7, 0.125, 3}, 0);

    // An organised binary PCD (as a depth camera writes it): rows of NaN where nothing was seen.
    std::string pcd =
        "# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 2\n"
        "HEIGHT 2\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 4\nDATA binary\n";
    const float nan = std::nanf("");
    for (float v : {1.f, 2.f, 3.f, nan, nan, nan, 4.f, 5.f, 6.f, nan, 0.f, 0.f})
        pcd.append(reinterpret_cast<const char*>(&v), 4);
    spit(dir / "organised.pcd", pcd);
    const auto organised = read_point_cloud(dir / "organised.pcd", "organised.pcd");
    ASSERT_EQ(organised->points_.size(), 2u);
    expect_near(organised->points_[1], {4, 5, 6}, 0);
}

// ---------------------------------------------------------------------------------------------------------
// Mesh formats and writers

TEST(MeshFormats, BinaryStlWhoseHeaderSaysSolidAndPolygonsInObj) {
    TempDir dir;
    open3d::geometry::TriangleMesh square;
    square.vertices_ = {{0, 0, 0}, {2, 0, 0}, {2, 2, 0}, {0, 2, 0}};
    square.triangles_ = {{0, 1, 2}, {0, 2, 3}};
    write_mesh(dir / "square.stl", square);
    // Many CAD programs start the binary header with "solid"; the size says binary.
    std::string bytes = slurp(dir / "square.stl");
    bytes.replace(0, 10, "solid CAD ");
    spit(dir / "solid_header.stl", bytes);
    const auto mesh = read_mesh(dir / "solid_header.stl", "solid_header.stl");
    EXPECT_EQ(mesh->vertices_.size(), 4u);  // the corners each facet repeats are shared
    EXPECT_EQ(mesh->triangles_.size(), 2u);
    EXPECT_NEAR(mesh->GetSurfaceArea(), 4.0, 1e-9);
    expect_near(mesh->triangle_normals_[0], {0, 0, 1}, 1e-12);

    spit(dir / "quad.obj",
         "# a square as one polygon\nv 0 0 0\nv 2 0 0\nv 2 2 0\nv 0 2 0\nvn 0 0 1\nf 1//1 2//1 3//1 -1//1\n");
    const auto quad = read_mesh(dir / "quad.obj", "quad.obj", 10.0);
    EXPECT_EQ(quad->triangles_.size(), 2u);
    EXPECT_NEAR(quad->GetSurfaceArea(), 400.0, 1e-9);

    spit(dir / "points.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\n");
    const ModelSource points = read_model(dir / "points.obj", "points.obj");
    ASSERT_TRUE(points.points);
    EXPECT_EQ(points.points->points_.size(), 3u);
}

TEST(Writers, PointCloudRoundTripsThroughBinaryPly) {
    TempDir dir;
    open3d::geometry::PointCloud cloud;
    for (int i = 0; i < 500; ++i) {
        cloud.points_.emplace_back(i * 0.25, -i * 0.5, 1000.0 + i);
        cloud.normals_.push_back(Eigen::Vector3d(1, i, 2).normalized());
        cloud.colors_.emplace_back(i % 2, 0.5, 1.0);
    }
    write_point_cloud(dir / "out/cloud.ply", cloud, "units mm");
    const auto back = read_point_cloud(dir / "out/cloud.ply", "cloud.ply");
    ASSERT_EQ(back->points_.size(), cloud.points_.size());
    ASSERT_TRUE(back->HasNormals());
    for (std::size_t i = 0; i < cloud.points_.size(); ++i) {
        expect_near(back->points_[i], cloud.points_[i], 1e-4);  // float precision at 1500
        expect_near(back->normals_[i], cloud.normals_[i], 1e-6);
    }
    // Written atomically: nothing but the file in the folder.
    EXPECT_EQ(std::distance(fs::directory_iterator(dir / "out"), fs::directory_iterator()), 1);
}

TEST(Writers, MeshRoundTripsThroughBinaryStl) {
    TempDir dir;
    const auto bunny =
        read_mesh(data("stanford_bunny/reconstruction_bun_zipper_res4.ply"), "res4.ply", 1000.0);
    write_mesh(dir / "bunny.stl", *bunny, "units mm");
    EXPECT_EQ(fs::file_size(dir / "bunny.stl"), 84 + 50 * bunny->triangles_.size());
    EXPECT_NE(slurp(dir / "bunny.stl").rfind("solid", 0), 0u);
    const auto back = read_mesh(dir / "bunny.stl", "bunny.stl");
    EXPECT_EQ(back->triangles_.size(), bunny->triangles_.size());
    EXPECT_EQ(back->vertices_.size(), bunny->vertices_.size());
    EXPECT_NEAR(back->GetSurfaceArea(), bunny->GetSurfaceArea(), 1e-4 * bunny->GetSurfaceArea());
    expect_near(back->GetMinBound(), bunny->GetMinBound(), 1e-4);
    expect_near(back->GetMaxBound(), bunny->GetMaxBound(), 1e-4);
}

// ---------------------------------------------------------------------------------------------------------
// Job loading

namespace {

/// A job folder: a cube fiducial model in metres (STL), reference surfaces as points (PLY), a final part
/// (OBJ), two scans (PLY, one in metres).
struct JobFolder {
    TempDir dir;
    JobFolder() {
        open3d::geometry::TriangleMesh cube;
        for (int i = 0; i < 8; ++i)
            cube.vertices_.emplace_back(0.01 * (i & 1), 0.02 * ((i >> 1) & 1), 0.03 * (i >> 2));
        cube.triangles_ = {{0, 2, 1}, {1, 2, 3}, {4, 5, 6}, {5, 7, 6}, {0, 1, 4}, {1, 5, 4},
                           {2, 6, 3}, {3, 6, 7}, {0, 4, 2}, {2, 4, 6}, {1, 3, 5}, {3, 7, 5}};
        write_mesh(dir / "models/cube_m.stl", cube);
        open3d::geometry::PointCloud pts;
        for (int i = 0; i < 100; ++i) pts.points_.emplace_back(i, 2 * i, 3);
        write_point_cloud(dir / "models/reference.ply", pts);
        write_point_cloud(dir / "scans/scan_01.ply", pts);
        open3d::geometry::PointCloud pts_m;
        for (const auto& p : pts.points_) pts_m.points_.push_back(p / 1000.0);
        write_point_cloud(dir / "scans/scan_02_m.ply", pts_m);
        spit(dir / "models/part.obj", "v 0 0 0\nv 10 0 0\nv 0 10 0\nf 1 2 3\n");
    }
    fs::path write(const std::string& text, const std::string& name = "job.yaml") {
        spit(dir / name, text);
        return dir / name;
    }
};

const char* kGoodJob = R"(units: mm
scanner: {point_spacing: 0.38, noise: 0.13}
machine:
  axes:
    - {name: A, type: rotary, direction: [2, 0, 0], point: [0, 10, 0]}
    - {name: X, type: linear, direction: [1, 0, 0]}
fiducials:
  - name: cube
    model: {file: models/cube_m.stl, units: m}
    pose: {origin: [60, -95, -40], euler_xyz_deg: [10, 20, 30]}
    moves_with: [A]
    probed_at: {A: 45}
    pose_sigma: 0.01
  - name: slab
    model: models/reference.ply
    pose: {matrix: [[0, -1, 0, 1], [1, 0, 0, 2], [0, 0, 1, 3], [0, 0, 0, 1]]}
workpiece:
  reference_surfaces: models/reference.ply
  datum: {origin: [-76.2, -12.7, 20.32], euler_xyz_deg: [0, 0, 90]}
  final_part: models/part.obj
  moves_with: [A]
  region: {min: [-120, -60, -20], max: [0, 40, 60]}
scans:
  - {file: scans/scan_01.ply, axes: {A: 0}}
  - {file: scans/scan_02_m.ply, units: m, axes: {A: 45, X: -5}}
  - scans/scan_01.ply
)";

}  // namespace

TEST(LoadJob, EveryFieldAndPerFileUnits) {
    JobFolder f;
    const Job job = load_job(f.write(kGoodJob));
    EXPECT_EQ(job.units, "mm");
    EXPECT_DOUBLE_EQ(*job.scanner.point_spacing, 0.38);
    EXPECT_DOUBLE_EQ(*job.scanner.noise, 0.13);
    ASSERT_EQ(job.machine.axes.size(), 2u);
    EXPECT_EQ(job.machine.axes[0].type, AxisType::Rotary);
    expect_near(job.machine.axes[0].direction, {1, 0, 0}, 1e-15);  // normalised
    expect_near(job.machine.axes[0].point, {0, 10, 0}, 0);
    EXPECT_EQ(job.machine.axes[1].type, AxisType::Linear);

    ASSERT_EQ(job.fiducials.size(), 2u);
    const Fiducial& cube = job.fiducials[0];
    EXPECT_EQ(cube.name, "cube");
    EXPECT_EQ(cube.model.file, "models/cube_m.stl");
    ASSERT_TRUE(cube.model.mesh);
    // The model is in metres, the job in millimetres: 0.01 x 0.02 x 0.03 m becomes 10 x 20 x 30 mm.
    expect_near(cube.model.mesh->GetMaxBound(), {10, 20, 30}, 1e-4);
    EXPECT_EQ(cube.model.mesh->triangles_.size(), 12u);
    EXPECT_LT(
        pose_error(cube.T_machine_fiducial, pose_from_origin_euler({60, -95, -40}, {10, 20, 30})).translation,
        1e-12);
    EXPECT_LT(pose_error(cube.T_machine_fiducial, pose_from_origin_euler({60, -95, -40}, {10, 20, 30}))
                  .rotation_deg,
              1e-9);
    EXPECT_EQ(cube.moves_with, std::vector<std::string>{"A"});
    EXPECT_DOUBLE_EQ(cube.probed_at.at("A"), 45.0);
    EXPECT_DOUBLE_EQ(cube.pose_sigma, 0.01);

    const Fiducial& slab = job.fiducials[1];
    ASSERT_TRUE(slab.model.points);
    EXPECT_EQ(slab.model.points->points_.size(), 100u);
    expect_near(slab.T_machine_fiducial * Eigen::Vector3d(1, 0, 0), {1, 3, 3}, 1e-12);  // R = Rz(90)
    EXPECT_TRUE(slab.moves_with.empty());
    EXPECT_TRUE(slab.probed_at.empty());

    ASSERT_TRUE(job.workpiece.reference_surfaces.points);
    expect_near(job.workpiece.T_machine_workpiece.translation(), {-76.2, -12.7, 20.32}, 1e-12);
    ASSERT_TRUE(job.workpiece.final_part);
    ASSERT_TRUE(job.workpiece.final_part->mesh);
    EXPECT_EQ(job.workpiece.moves_with, std::vector<std::string>{"A"});
    ASSERT_TRUE(job.workpiece.region);
    expect_near(job.workpiece.region->min(), {-120, -60, -20}, 0);

    ASSERT_EQ(job.scans.size(), 3u);
    EXPECT_EQ(job.scans[0].file, "scans/scan_01.ply");
    EXPECT_DOUBLE_EQ(job.scans[1].axes.at("X"), -5.0);
    EXPECT_TRUE(job.scans[2].axes.empty());
    // The scan in metres comes out in millimetres, the same as the one written in millimetres.
    ASSERT_EQ(job.scans[1].points->points_.size(), 100u);
    for (std::size_t i = 0; i < 100; ++i)
        expect_near(job.scans[1].points->points_[i], job.scans[0].points->points_[i], 1e-3);
}

TEST(LoadJob, JsonIsAcceptedAndInchesConvertFiles) {
    JobFolder f;
    const fs::path json = f.write(R"({
	"units": "in",
	"fiducials": [{"name": "cube", "model": {"file": "models/cube_m.stl", "units": "m"},
	               "pose": {"origin": [1, 2, 3]}}],
	"workpiece": {"reference_surfaces": {"file": "models/reference.ply", "units": "mm"}},
	"scans": [{"file": "scans/scan_01.ply"}]
})",
                                  "job.json");
    const Job job = load_job(json);
    EXPECT_EQ(job.units, "in");
    expect_near(job.fiducials[0].model.mesh->GetMaxBound(), Eigen::Vector3d(10, 20, 30) / 25.4, 1e-5);
    expect_near(job.workpiece.reference_surfaces.points->points_[1], Eigen::Vector3d(1, 2, 3) / 25.4, 1e-6);
    EXPECT_TRUE(job.workpiece.T_machine_workpiece.isApprox(Eigen::Isometry3d::Identity()));
    EXPECT_TRUE(job.machine.axes.empty());
}

TEST(LoadJob, EveryProblemNamesTheJobFileAndTheField) {
    JobFolder f;
    const std::string good = kGoodJob;
    const auto replaced = [&](const std::string& from, const std::string& to) {
        std::string s = good;
        const std::size_t at = s.find(from);
        EXPECT_NE(at, std::string::npos) << from;
        return s.replace(at, from.size(), to);
    };
    const struct {
        std::string text, phrase;
    } cases[] = {
        {replaced("units: mm", "units: furlong"), "units: unknown unit 'furlong'"},
        {replaced("euler_xyz_deg: [10, 20, 30]", "euler_xyz_deg: [10, 20]"),
         "fiducials[0].pose.euler_xyz_deg: expected 3 numbers, found 2 items (line 10)"},
        {replaced("origin: [60, -95, -40]", "origin: [60, .nan, -40]"),
         "fiducials[0].pose.origin[1]: expected a"},
        {replaced("origin: [60, -95, -40]", "origin: [60, 1e999, -40]"), "fiducials[0].pose.origin[1]"},
        {replaced("origin: [60, -95, -40]", "origin: [60, ten, -40]"),
         "fiducials[0].pose.origin[1]: expected a number, found 'ten'"},
        {replaced("[0, -1, 0, 1], [1, 0, 0, 2]", "[0, -1, 0, 1], [2, 0, 0, 2]"),
         "fiducials[1].pose.matrix: rotation part is not orthonormal"},
        {replaced(", [0, 0, 0, 1]]}", "]}"),
         "fiducials[1].pose.matrix: expected 4 rows of 4 numbers, found 3 rows"},
        {replaced("name: slab", "name: cube"), "fiducials[1].name: fiducial name 'cube' is already used"},
        {replaced("moves_with: [A]\n    probed_at", "moves_with: [B]\n    probed_at"),
         "fiducials[0].moves_with[0]: machine.axes has no axis 'B'"},
        {replaced("axes: {A: 45, X: -5}", "axes: {A: 45, Q: -5}"),
         "scans[1].axes.Q: machine.axes has no axis 'Q'"},
        {replaced("point: [0, 10, 0]", "pnt: [0, 10, 0]"), "machine.axes[0].pnt: unknown field"},
        {replaced(", point: [0, 10, 0]", ""), "machine.axes[0].point: missing"},
        {replaced("type: linear", "type: sliding"), "machine.axes[1].type: expected linear or rotary"},
        {replaced("direction: [1, 0, 0]", "direction: [0, 0, 0]"),
         "machine.axes[1].direction: must not be zero"},
        {replaced("units: m,", "units: parsec,"), "scans[1].units: unknown unit 'parsec'"},
        {replaced("region: {min: [-120, -60, -20]", "region: {min: [120, -60, -20]"),
         "workpiece.region: max must"},
        {replaced("point_spacing: 0.38", "point_spacing: -1"),
         "scanner.point_spacing: must be greater than 0"},
        {good.substr(0, good.find("scans:")), ": scans: missing"},
        {good.substr(0, good.find("scans:")) + "scans: []\n", "scans: expected a list of one or more scans"},
        {replaced("pose_sigma: 0.01", "pose_sigma: 0.01\n    pose_sigma: 0.02"),
         "fiducials[0].pose_sigma: given twice"},
        {replaced("units: mm", "units: mm\nfiducals: []"), "fiducals: unknown field"},
        {"units: mm\nfiducials: [\n", "not valid YAML or JSON"},
        {"- just\n- a list\n", "expected a mapping"},
        {"", "the job file is empty"},
    };
    for (const auto& c : cases) {
        const fs::path p = f.write(c.text);
        expect_input_error([&] { load_job(p); }, p.string(), c.phrase);
    }
    const std::string no_fiducials =
        "units: mm\nfiducials: []\nworkpiece: {reference_surfaces: a.ply}\nscans: [a.ply]\n";
    expect_input_error([&] { load_job(f.write(no_fiducials)); }, (f.dir / "job.yaml").string(),
                       "fiducials: expected a list of one or more fiducials");
    expect_input_error([&] { load_job(f.dir / "nope.yaml"); }, (f.dir / "nope.yaml").string(),
                       "no such file");
}

TEST(LoadJob, ABadDataFileIsNamedAsTheJobWritesIt) {
    JobFolder f;
    std::string text = kGoodJob;
    text.replace(text.find("models/part.obj"), 15, "models/missing.stl");
    expect_input_error([&] { load_job(f.write(text)); }, "models/missing.stl", "no such file");

    // The first bad file in the job's order is the one reported, however the reading threads finish.
    spit(f.dir / "scans/nan.xyz", "nan nan nan\n");
    text = kGoodJob;
    text.replace(text.find("- scans/scan_01.ply"), 19, "- scans/nan.xyz\n  - scans/absent.ply");
    for (int threads : {1, 4})
        expect_input_error([&] { load_job(f.write(text), LoadOptions{threads}); }, "scans/nan.xyz",
                           "no finite points");
}

// ---------------------------------------------------------------------------------------------------------
// Outputs

namespace {

Job small_job() {
    Job job;
    job.units = "mm";
    job.workpiece.T_machine_workpiece = pose_from_origin_euler({-76.2, -12.7, 20.32}, {0, 0, 179});
    job.workpiece.reference_surfaces.file = "models/reference.ply";
    Fiducial fid;
    fid.name = "A<&>";
    fid.model.file = "models/fiducial_A.stl";
    job.fiducials.push_back(fid);
    for (const char* file : {"scans/scan_01.ply", "scans/<script>alert(1)</script>.ply"}) {
        Scan s;
        s.file = file;
        s.axes["A"] = 45;
        job.scans.push_back(s);
    }
    return job;
}

JobResult located_result(const Job& job) {
    JobResult r;
    r.units = job.units;
    ScanResult good;
    good.file = job.scans[0].file;
    good.valid = true;
    good.fiducials = {"A<&>"};
    good.score = 5.1;
    good.rmse = 0.12;
    good.T_machine_scan = pose_from_origin_euler({1, 2, 3}, {0, 90, 0});
    good.points = 1234;
    good.point_spacing = 0.38;
    good.noise = 0.13;
    FiducialFit fit;
    fit.fiducial = "A<&>";
    fit.valid = true;
    fit.score = 5.1;
    fit.coverage = 0.8;
    fit.inliers = 900;
    good.fits.push_back(fit);
    ScanResult bad;
    bad.file = job.scans[1].file;
    bad.reason = "no fiducial fits: A: coverage 0.02 < 0.3 [\"seen\"  2, of 9]";
    bad.fits.push_back(fit);
    bad.fits.back().valid = false;
    bad.fits.back().reason = "coverage 0.02 < 0.3";
    r.scans = {good, bad};
    r.workpiece.valid = true;
    r.workpiece.T_machine_workpiece = pose_from_origin_euler({-76.3, -12.9, 20.5}, {0.5, -0.1, -179.5});
    r.workpiece.rmse = 0.09;
    r.workpiece.points = 183422;
    r.merged = std::make_shared<open3d::geometry::PointCloud>();
    for (int i = 0; i < 20000; ++i)
        r.merged->points_.emplace_back(-120 + (i % 200) * 0.6, -60 + (i / 200) * 1.0, 20 + 0.1 * std::sin(i));
    r.stock = std::make_shared<open3d::geometry::TriangleMesh>();
    r.stock->vertices_ = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}};
    r.stock->triangles_ = {{0, 1, 2}};
    return r;
}

Eigen::Matrix4d matrix_of(const nlohmann::json& j) {
    Eigen::Matrix4d M;
    for (int r = 0; r < 4; ++r)
        for (int c = 0; c < 4; ++c) M(r, c) = j.at(r).at(c).get<double>();
    return M;
}

}  // namespace

TEST(Outputs, ResultJsonHoldsSpecFieldsAndAdditions) {
    TempDir dir;
    const Job job = small_job();
    const JobResult result = located_result(job);
    const auto written = write_outputs(dir / "out", job, result, "job.yaml");
    EXPECT_EQ(written.back(), dir / "out/result.json");  // last, when the others are whole

    const auto j = nlohmann::json::parse(slurp(dir / "out/result.json"));
    EXPECT_EQ(j.at("status"), "located");
    EXPECT_EQ(j.at("units"), "mm");
    ASSERT_EQ(j.at("scans").size(), 2u);
    const auto& s0 = j.at("scans")[0];
    EXPECT_EQ(s0.at("file"), "scans/scan_01.ply");
    EXPECT_EQ(s0.at("status"), "registered");
    EXPECT_EQ(s0.at("fiducials"), nlohmann::json::array({"A<&>"}));
    EXPECT_DOUBLE_EQ(s0.at("score").get<double>(), 5.1);
    EXPECT_DOUBLE_EQ(s0.at("rmse").get<double>(), 0.12);
    EXPECT_LT((matrix_of(s0.at("T_machine_scan")) - result.scans[0].T_machine_scan.matrix()).norm(), 1e-8);
    EXPECT_EQ(matrix_of(s0.at("T_machine_scan"))(0, 0), 0.0);  // cos 90°, not 6e-17
    EXPECT_EQ(s0.at("message"), "");
    EXPECT_EQ(s0.at("points"), 1234);
    EXPECT_DOUBLE_EQ(s0.at("point_spacing").get<double>(), 0.38);
    EXPECT_DOUBLE_EQ(s0.at("axes").at("A").get<double>(), 45.0);
    ASSERT_EQ(s0.at("fits").size(), 1u);
    EXPECT_EQ(s0.at("fits")[0].at("fiducial"), "A<&>");
    EXPECT_EQ(s0.at("fits")[0].at("inliers"), 900);
    EXPECT_EQ(s0.at("fits")[0].at("searched"), true);
    const auto& s1 = j.at("scans")[1];
    EXPECT_EQ(s1.at("status"), "rejected");
    EXPECT_TRUE(s1.at("T_machine_scan").is_null());
    EXPECT_EQ(s1.at("message"), "no fiducial fits: A: coverage 0.02 < 0.3 [\"seen\"  2, of 9]");
    // Arrays of numbers sit on one line: a matrix reads as four rows.
    EXPECT_NE(slurp(dir / "out/result.json").find("[0.0, 0.0, 0.0, 1.0]"), std::string::npos);

    const auto& w = j.at("workpiece");
    EXPECT_LT((matrix_of(w.at("T_machine_workpiece")) - result.workpiece.T_machine_workpiece.matrix()).norm(),
              1e-8);
    const auto vec = [](const nlohmann::json& a) {
        return Eigen::Vector3d(a.at(0).get<double>(), a.at(1).get<double>(), a.at(2).get<double>());
    };
    expect_near(vec(w.at("origin")), {-76.3, -12.9, 20.5}, 1e-9);
    expect_near(vec(w.at("euler_xyz_deg")), {0.5, -0.1, -179.5}, 1e-8);
    // Located minus nominal; the yaw difference wraps across ±180: -179.5 - 179 = 1.5, not -358.5.
    expect_near(vec(w.at("deviation").at("origin")), {-0.1, -0.2, 0.18}, 1e-9);
    expect_near(vec(w.at("deviation").at("euler_xyz_deg")), {0.5, -0.1, 1.5}, 1e-8);
    EXPECT_DOUBLE_EQ(w.at("rmse").get<double>(), 0.09);
    EXPECT_EQ(w.at("points"), 183422);
    expect_near(vec(w.at("nominal").at("origin")), {-76.2, -12.7, 20.32}, 1e-9);

    // The model files are whole and readable; nothing else is left in the folder.
    EXPECT_EQ(read_point_cloud(dir / "out/merged.ply", "merged.ply")->points_.size(), 20000u);
    EXPECT_EQ(read_mesh(dir / "out/stock.stl", "stock.stl")->triangles_.size(), 1u);
    EXPECT_FALSE(fs::exists(dir / "out/final_part_located.stl"));
    std::set<std::string> names;
    for (const auto& e : fs::directory_iterator(dir / "out")) names.insert(e.path().filename().string());
    EXPECT_EQ(names, (std::set<std::string>{"cam", "merged.ply", "report.html", "result.json", "stock.stl"}));
    // The stock for CAM, in the located workpiece frame (no final part: no placement, no cam/final_part.stl).
    EXPECT_EQ(read_mesh(dir / "out/cam/stock.stl", "cam/stock.stl")->triangles_.size(), 1u);
    EXPECT_FALSE(fs::exists(dir / "out/cam/final_part.stl"));
}

TEST(Outputs, NotLocatedStillWritesResultJsonAndClearsOldModels) {
    TempDir dir;
    const Job job = small_job();
    write_outputs(dir / "out", job, located_result(job));
    ASSERT_TRUE(fs::exists(dir / "out/merged.ply"));

    JobResult r;
    r.units = "mm";
    r.workpiece.reason = "no scan could be registered to the machine";
    write_outputs(dir / "out", job, r);
    const auto j = nlohmann::json::parse(slurp(dir / "out/result.json"));
    EXPECT_EQ(j.at("status"), "not_located");
    EXPECT_EQ(j.at("workpiece").at("message"), "no scan could be registered to the machine");
    EXPECT_TRUE(j.at("workpiece").at("T_machine_workpiece").is_null());
    EXPECT_TRUE(j.at("workpiece").at("deviation").is_null());
    EXPECT_FALSE(fs::exists(dir / "out/merged.ply"));  // of the earlier run, gone
    EXPECT_FALSE(fs::exists(dir / "out/stock.stl"));
    EXPECT_TRUE(fs::exists(dir / "out/report.html"));
}

TEST(Outputs, ReportIsSelfContainedEscapedAndDrawsThreeViews) {
    const Job job = small_job();
    const JobResult result = located_result(job);
    const std::string html = render_report_html(job, result, {"jobs/<b>job</b>.yaml", 3000});
    EXPECT_EQ(html.rfind("<!DOCTYPE html>", 0), 0u);
    // The scan named "<script>..." is escaped, in the tables and in the 3D view's data; the page's only
    // scripts are the 3D view's, inline: its data, three.js, OrbitControls and the drawing.
    EXPECT_EQ(html.find("<script>alert"), std::string::npos);
    EXPECT_NE(html.find("\\u003cscript>alert(1)\\u003c/script>"), std::string::npos);
    std::size_t scripts = 0;
    for (std::size_t at = 0; (at = html.find("<script", at)) != std::string::npos; ++at) {
        ++scripts;
        EXPECT_EQ(html.substr(at, html.find('>', at) - at).find("src"), std::string::npos);
    }
    EXPECT_EQ(scripts, 4u);
    EXPECT_EQ(html.find("No 3D view"), std::string::npos);
    EXPECT_NE(html.find("scans/&lt;script&gt;alert(1)&lt;/script&gt;.ply"), std::string::npos);
    EXPECT_NE(html.find("A&lt;&amp;&gt;"), std::string::npos);
    EXPECT_EQ(html.find("<b>job</b>"), std::string::npos);
    EXPECT_EQ(html.find("<img"), std::string::npos);  // no external images, scripts or styles
    EXPECT_EQ(html.find("<link"), std::string::npos);
    std::size_t svgs = 0, circles = 0;
    for (std::size_t at = 0; (at = html.find("<svg", at)) != std::string::npos; ++at) ++svgs;
    for (std::size_t at = 0; (at = html.find("<circle", at)) != std::string::npos; ++at) ++circles;
    EXPECT_EQ(svgs, 3u);
    EXPECT_LE(circles, 3u * 3000u);  // subsampled
    EXPECT_GE(circles, 3u * 2000u);
    EXPECT_NE(html.find("no fiducial fits: A: coverage 0.02 &lt; 0.3"), std::string::npos);
    EXPECT_NE(html.find("-0.100"), std::string::npos);  // the deviation in X, mm to 3 decimals
    EXPECT_EQ(escape_html("a<b>&\"'"), "a&lt;b&gt;&amp;&quot;&#39;");

    // Without three.js on the machine the page says so, draws the pictures, and has no script.
    ReportOptions without;
    without.view3d.three_js_dir = "/nonexistent/three";
    const std::string plain = render_report_html(job, result, without);
    EXPECT_NE(plain.find("No 3D view: it needs three.js"), std::string::npos);
    EXPECT_EQ(plain.find("<script"), std::string::npos);
    EXPECT_NE(plain.find("<svg"), std::string::npos);
}

TEST(Outputs, WarningsAreListedInResultJsonAndTheReportShowsThemInAmber) {
    const Job job = small_job();
    JobResult result = located_result(job);
    const std::string plain = render_report_html(job, result, {"job.yaml", 3000});
    EXPECT_NE(plain.find("banner ok"), std::string::npos);
    EXPECT_TRUE(nlohmann::json::parse(result_json(job, result)).at("warnings").empty());
    result.warnings = {"scans/s1.ply: fiducial C is left out: it lies 0.5 mm from where A and B put it"};
    const auto j = nlohmann::json::parse(result_json(job, result));
    EXPECT_EQ(j.at("status"), "located");  // still located, and listed
    ASSERT_EQ(j.at("warnings").size(), 1u);
    EXPECT_EQ(j.at("warnings")[0], result.warnings[0]);
    const std::string html = render_report_html(job, result, {"job.yaml", 3000});
    EXPECT_NE(html.find("banner warn"), std::string::npos);
    EXPECT_NE(html.find("<b>Workpiece located with warnings</b>"),
              std::string::npos);  // the terminal's words
    EXPECT_EQ(html.find("banner ok"), std::string::npos);
    // Euler angles are not named like the machine's rotary axes A, B, C (issue 27).
    EXPECT_NE(html.find("<th>rot X (°)</th><th>rot Y (°)</th><th>rot Z (°)</th>"), std::string::npos);
    EXPECT_EQ(html.find("<th>A (°)</th>"), std::string::npos);
    EXPECT_NE(html.find("fiducial C is left out"), std::string::npos);
}
