// Issue 3: prepared fiducial models kept on disk between jobs (io/model_cache.hpp). A model from the cache
// is prepare_model's to the last bit; a damaged file, one of another model, or a folder that cannot be
// written never changes a result, and a job run from the cache gives the same bits as one without it.
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstring>
#include <filesystem>
#include <fstream>

#include "partloc/core/surface.hpp"
#include "partloc/io/model_cache.hpp"
#include "partloc/pipeline/run.hpp"
#include "partloc/sim/scenario.hpp"
#include "test_util.hpp"

namespace fs = std::filesystem;
using namespace partloc;

namespace {

class ModelCacheTest : public ::testing::Test {
  protected:
    static void SetUpTestSuite() {
        open3d::utility::SetVerbosityLevel(open3d::utility::VerbosityLevel::Error);
        sim::ScenarioOptions o;
        o.a_values = {0.0, 90.0};
        o.scans_per_position = 1;
        job_ = new sim::SimulatedJob(sim::simulate_random_cell(3, o));
    }
    static void TearDownTestSuite() {
        delete job_;
        job_ = nullptr;
    }
    void SetUp() override {
        static std::atomic<int> n{0};
        dir_ = fs::temp_directory_path() /
               ("partloc_test_model_cache_" + std::to_string(::getpid()) + "_" + std::to_string(n++));
        fs::remove_all(dir_);
    }
    void TearDown() override {
        std::error_code ec;
        fs::remove_all(dir_, ec);
    }

    static const Job& job() { return job_->job; }
    static const open3d::geometry::TriangleMesh* mesh(std::size_t k) {
        return job().fiducials[k].model.mesh.get();
    }
    /// Spacings as run_job chooses them for fiducial k: 1/150 and 0.04 of its size.
    static double dense(std::size_t k) {
        return bounding_box(job().fiducials[k].model).diagonal().norm() / 150.0;
    }
    static double sampling(std::size_t k) {
        return 0.04 * bounding_box(job().fiducials[k].model).diagonal().norm();
    }
    PreparedModel cached(io::ModelCache& cache, std::size_t k) {
        return cache.prepare("f" + std::to_string(k), mesh(k), nullptr, dense(k), sampling(k));
    }
    PreparedModel fresh(std::size_t k) {
        return prepare_model("f" + std::to_string(k), mesh(k), nullptr, dense(k), sampling(k));
    }

    static sim::SimulatedJob* job_;
    fs::path dir_;
};
sim::SimulatedJob* ModelCacheTest::job_ = nullptr;

template <class T>
bool same_bytes(const std::vector<T>& a, const std::vector<T>& b) {
    return a.size() == b.size() && std::memcmp(a.data(), b.data(), a.size() * sizeof(T)) == 0;
}

void expect_same_frame(const CellFrame& a, const CellFrame& b) {
    EXPECT_EQ(a.origin, b.origin);
    EXPECT_EQ(a.cell, b.cell);
    EXPECT_EQ(a.inv_cell, b.inv_cell);
    EXPECT_EQ(a.nx, b.nx);
    EXPECT_EQ(a.ny, b.ny);
    EXPECT_EQ(a.nz, b.nz);
}

/// Every part of the prepared model, bit for bit, and the searches built on them.
void expect_same_model(const PreparedModel& a, const PreparedModel& b) {
    EXPECT_EQ(a.name, b.name);
    EXPECT_EQ(a.sampling, b.sampling);
    EXPECT_EQ(a.dense.points, b.dense.points);
    EXPECT_EQ(a.dense.normals, b.dense.normals);
    ASSERT_TRUE(a.dense.cloud && b.dense.cloud);
    EXPECT_EQ(a.dense.cloud->points_, b.dense.cloud->points_);
    EXPECT_EQ(a.dense.cloud->normals_, b.dense.cloud->normals_);
    EXPECT_EQ(a.dense.center, b.dense.center);
    EXPECT_EQ(a.dense.diameter, b.dense.diameter);
    EXPECT_EQ(a.dense.spacing, b.dense.spacing);
    expect_same_frame(a.dense.grid.frame(), b.dense.grid.frame());
    EXPECT_EQ(a.dense.grid.order(), b.dense.grid.order());
    EXPECT_EQ(a.dense.grid.starts(), b.dense.grid.starts());
    EXPECT_EQ(a.dense.grid.distances(), b.dense.grid.distances());
    ASSERT_TRUE(a.dense.coarse && b.dense.coarse);
    expect_same_frame(a.dense.coarse->frame(), b.dense.coarse->frame());
    EXPECT_EQ(a.dense.coarse->reach(), b.dense.coarse->reach());
    EXPECT_EQ(a.dense.coarse->cells(), b.dense.coarse->cells());
    ASSERT_TRUE(a.ppf && b.ppf);
    EXPECT_EQ(a.ppf->points(), b.ppf->points());
    EXPECT_EQ(a.ppf->normals(), b.ppf->normals());
    EXPECT_EQ(a.ppf->offsets(), b.ppf->offsets());
    EXPECT_TRUE(same_bytes(a.ppf->entries(), b.ppf->entries()));
    EXPECT_EQ(a.ppf->max_bucket(), b.ppf->max_bucket());
    EXPECT_EQ(a.ppf->diameter(), b.ppf->diameter());
    EXPECT_EQ(a.ppf->center(), b.ppf->center());
    // The searches over them: the exact grid, and which keys vote.
    for (int i = 0; i < 200; ++i) {
        const Eigen::Vector3d p = a.dense.center + 0.6 * a.dense.diameter * Eigen::Vector3d::Random();
        double da = 0.0, db = 0.0;
        EXPECT_EQ(a.dense.nearest(p, &da), b.dense.nearest(p, &db));
        EXPECT_EQ(da, db);
        EXPECT_EQ(a.dense.coarse->nearest(p), b.dense.coarse->nearest(p));
    }
    for (int k = 0; k + 1 < static_cast<int>(a.ppf->offsets().size()); ++k)
        ASSERT_EQ(a.ppf->votes(k), b.ppf->votes(k)) << "key " << k;
}

std::vector<fs::path> model_files(const fs::path& dir) {
    std::vector<fs::path> out;
    std::error_code ec;
    for (fs::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec))
        if (it->path().extension() == ".model") out.push_back(it->path());
    return out;
}

}  // namespace

TEST_F(ModelCacheTest, AHitGivesWhatPrepareModelGives) {
    const PreparedModel want = fresh(0);
    {
        io::ModelCache cache(dir_);
        expect_same_model(cached(cache, 0), want);  // prepared, and written
        EXPECT_EQ(cache.hits(), 0u);
        EXPECT_EQ(cache.misses(), 1u);
    }
    ASSERT_EQ(model_files(dir_).size(), 1u);
    EXPECT_EQ(model_files(dir_).front(),
              io::ModelCache(dir_).file_for(mesh(0), nullptr, dense(0), sampling(0)));
    io::ModelCache again(dir_);  // another run
    expect_same_model(cached(again, 0), want);
    EXPECT_EQ(again.hits(), 1u);
    EXPECT_EQ(again.misses(), 0u);
    EXPECT_TRUE(again.problems().empty());
}

// A fiducial given as points with normals (prepare_model's other path: its coarse samples by a voxel grid).
TEST_F(ModelCacheTest, APointModelToo) {
    const auto points = sample_mesh(*mesh(0), 0.5 * dense(0));
    ASSERT_TRUE(points->HasNormals());
    const auto prepare = [&](io::ModelCache* cache) {
        return cache ? cache->prepare("p", nullptr, points.get(), dense(0), sampling(0))
                     : prepare_model("p", nullptr, points.get(), dense(0), sampling(0));
    };
    const PreparedModel want = prepare(nullptr);
    io::ModelCache first(dir_);
    expect_same_model(prepare(&first), want);
    io::ModelCache again(dir_);
    expect_same_model(prepare(&again), want);
    EXPECT_EQ(again.hits(), 1u);
    EXPECT_TRUE(again.problems().empty());
}

TEST_F(ModelCacheTest, AnotherSpacingOrModelIsAnotherFile) {
    const io::ModelCache cache(dir_);
    const fs::path f = cache.file_for(mesh(0), nullptr, dense(0), sampling(0));
    EXPECT_EQ(f, cache.file_for(mesh(0), nullptr, dense(0), sampling(0)));
    EXPECT_NE(f, cache.file_for(mesh(0), nullptr, std::nextafter(dense(0), 1.0), sampling(0)));
    EXPECT_NE(f, cache.file_for(mesh(0), nullptr, dense(0), 1.01 * sampling(0)));
    auto moved = std::make_shared<open3d::geometry::TriangleMesh>(*mesh(0));
    moved->vertices_[0].x() += 1e-9;
    EXPECT_NE(f, cache.file_for(moved.get(), nullptr, dense(0), sampling(0)));
    // The same mesh given as points is another model (prepare_model samples it otherwise).
    open3d::geometry::PointCloud points;
    points.points_ = mesh(0)->vertices_;
    EXPECT_NE(f, cache.file_for(nullptr, &points, dense(0), sampling(0)));
    EXPECT_EQ(f.filename().string().size(), 64u + 6u);  // the SHA-256 in hex, ".model"
}

TEST_F(ModelCacheTest, ADamagedTruncatedOrForeignFileIsPreparedAgainAndRewritten) {
    const PreparedModel want = fresh(0);
    {
        io::ModelCache cache(dir_);
        cached(cache, 0);
    }
    const fs::path f0 = io::ModelCache(dir_).file_for(mesh(0), nullptr, dense(0), sampling(0));
    const fs::path f1 = io::ModelCache(dir_).file_for(mesh(0), nullptr, dense(0), 1.1 * sampling(0));
    {
        io::ModelCache cache(dir_);
        cache.prepare("f0", mesh(0), nullptr, dense(0), 1.1 * sampling(0));
    }
    const std::string good = test::slurp(f0);
    const auto expect_recovers = [&](const std::string& bytes, const std::string& phrase) {
        test::spit(f0, bytes);
        io::ModelCache cache(dir_);
        expect_same_model(cached(cache, 0), want);
        EXPECT_EQ(cache.misses(), 1u);
        ASSERT_EQ(cache.problems().size(), 1u);
        EXPECT_NE(cache.problems().front().find(phrase), std::string::npos) << cache.problems().front();
        EXPECT_EQ(test::slurp(f0), good) << "rewritten";
        io::ModelCache after(dir_);
        cached(after, 0);
        EXPECT_EQ(after.hits(), 1u);
        EXPECT_TRUE(after.problems().empty());
    };
    std::string flipped = good;
    flipped[good.size() / 2] ^= 0x10;  // one bit in the middle of the payload
    expect_recovers(flipped, "checksum");
    expect_recovers(good.substr(0, good.size() / 2), "truncated");
    expect_recovers(good.substr(0, 20), "not a model cache file");
    expect_recovers(test::slurp(f1), "holds another model");
    expect_recovers("", "not a model cache file");
}

TEST_F(ModelCacheTest, AFolderThatCannotBeWrittenLeavesTheModelAlone) {
    test::spit(dir_ / "file", "not a folder");
    io::ModelCache cache(dir_ / "file" / "cache");
    expect_same_model(cached(cache, 0), fresh(0));
    EXPECT_EQ(cache.misses(), 1u);
    ASSERT_EQ(cache.problems().size(), 1u);
    EXPECT_NE(cache.problems().front().find("cannot keep f0"), std::string::npos) << cache.problems().front();
}

TEST_F(ModelCacheTest, KeepsAtMostItsSizeTheLeastRecentlyUsedGoingFirst) {
    // Three models of fiducial 0 (three samplings) and their files' sizes.
    const auto at = [&](io::ModelCache& cache, int i) {
        return cache.prepare("f", mesh(0), nullptr, dense(0), (1.0 + 0.1 * i) * sampling(0));
    };
    std::uintmax_t size[3];
    fs::path file[3];
    {
        io::ModelCache sizes(dir_ / "sizes");
        for (int i = 0; i < 3; ++i) {
            at(sizes, i);
            file[i] =
                dir_ / sizes.file_for(mesh(0), nullptr, dense(0), (1.0 + 0.1 * i) * sampling(0)).filename();
            size[i] = fs::file_size(dir_ / "sizes" / file[i].filename());
        }
    }
    // Room for the first two; the third passes the limit, and the files used least recently go until a
    // quarter is free.
    const std::uintmax_t limit = std::max(size[0] + size[1], (size[0] + size[2]) * 4 / 3 + 4);
    ASSERT_GT(size[0] + size[1] + size[2], limit);
    io::ModelCache cache(dir_, limit);
    at(cache, 0);
    at(cache, 1);
    EXPECT_TRUE(fs::exists(file[0]) && fs::exists(file[1]));
    fs::last_write_time(file[0], fs::last_write_time(file[1]) - std::chrono::hours(1));
    at(cache, 0);  // a hit: file 0 is now the one used last, so file 1 goes
    EXPECT_EQ(cache.hits(), 1u);
    at(cache, 2);
    EXPECT_TRUE(fs::exists(file[0]));
    EXPECT_FALSE(fs::exists(file[1]));
    EXPECT_TRUE(fs::exists(file[2]));
    EXPECT_EQ(model_files(dir_).size(), 2u);
    EXPECT_TRUE(cache.problems().empty());
}

TEST_F(ModelCacheTest, ATableOrMapThatDoesNotFitIsRefused) {
    const PreparedModel m = fresh(0);
    const NearestMap& map = *m.dense.coarse;
    const std::size_t n = m.dense.points.size();
    EXPECT_NO_THROW(NearestMap(map.frame(), map.reach(), map.cells(), n));
    auto cells = map.cells();
    cells.pop_back();
    EXPECT_THROW(NearestMap(map.frame(), map.reach(), cells, n), std::invalid_argument);
    cells = map.cells();
    cells.back() = static_cast<std::int32_t>(n);
    EXPECT_THROW(NearestMap(map.frame(), map.reach(), cells, n), std::invalid_argument);

    const SampleGrid& g = m.dense.grid;
    const auto& pts = m.dense.points;
    EXPECT_NO_THROW(SampleGrid(pts, g.frame(), g.order(), g.starts(), g.distances()));
    auto order = g.order();
    order.back() = static_cast<std::uint32_t>(pts.size());
    EXPECT_THROW(SampleGrid(pts, g.frame(), order, g.starts(), g.distances()), std::invalid_argument);
    auto starts = g.starts();
    starts[1] = starts.back() + 1;
    EXPECT_THROW(SampleGrid(pts, g.frame(), g.order(), starts, g.distances()), std::invalid_argument);
    auto distances = g.distances();
    distances.pop_back();
    EXPECT_THROW(SampleGrid(pts, g.frame(), g.order(), g.starts(), distances), std::invalid_argument);

    const PpfModel& t = *m.ppf;
    PpfSettings s = t.settings();
    EXPECT_NO_THROW(PpfModel(t.points(), t.normals(), s, t.offsets(), t.entries(), t.max_bucket()));
    auto offsets = t.offsets();
    offsets.pop_back();
    EXPECT_THROW(PpfModel(t.points(), t.normals(), s, offsets, t.entries(), t.max_bucket()),
                 std::invalid_argument);
    auto entries = t.entries();
    ASSERT_FALSE(entries.empty());
    entries.front().row =
        static_cast<std::uint32_t>(t.points().size() * s.alpha_bins);  // past the last point
    EXPECT_THROW(PpfModel(t.points(), t.normals(), s, t.offsets(), entries, t.max_bucket()),
                 std::invalid_argument);
    entries.front().row = t.entries().front().row + 1;  // not a row's start
    EXPECT_THROW(PpfModel(t.points(), t.normals(), s, t.offsets(), entries, t.max_bucket()),
                 std::invalid_argument);
    entries = t.entries();
    entries.pop_back();
    EXPECT_THROW(PpfModel(t.points(), t.normals(), s, t.offsets(), entries, t.max_bucket()),
                 std::invalid_argument);
}

// The job from the cache, cold and warm, against the job without it: every registration, the part, the
// merged points, to the last bit.
TEST_F(ModelCacheTest, AJobFromTheCacheGivesTheSameBits) {
    JobResult r[3];
    io::ModelCache cold(dir_), warm(dir_);
    for (int i = 0; i < 3; ++i) {
        RunSettings rs;
        rs.build_stock = false;
        rs.models = i == 0 ? nullptr : i == 1 ? &cold : &warm;
        r[i] = run_job(job(), rs);
    }
    EXPECT_EQ(cold.hits(), 0u);
    EXPECT_EQ(warm.misses(), 0u);
    EXPECT_EQ(warm.hits(), job().fiducials.size());
    int registered = 0;
    for (int i = 1; i < 3; ++i) {
        ASSERT_EQ(r[i].scans.size(), r[0].scans.size());
        for (std::size_t s = 0; s < r[0].scans.size(); ++s) {
            EXPECT_EQ(r[i].scans[s].valid, r[0].scans[s].valid);
            EXPECT_EQ(r[i].scans[s].reason, r[0].scans[s].reason);
            EXPECT_TRUE(r[i].scans[s].T_machine_scan.matrix() == r[0].scans[s].T_machine_scan.matrix());
            registered += r[i].scans[s].valid;
        }
        ASSERT_TRUE(r[i].workpiece.valid && r[0].workpiece.valid);
        EXPECT_TRUE(r[i].workpiece.T_machine_workpiece.matrix() ==
                    r[0].workpiece.T_machine_workpiece.matrix());
        ASSERT_TRUE(r[i].merged && r[0].merged);
        EXPECT_EQ(r[i].merged->points_, r[0].merged->points_);
    }
    EXPECT_GE(registered, 2);
}
