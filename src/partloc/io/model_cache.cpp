#include "partloc/io/model_cache.hpp"

#include <openssl/evp.h>

#include <algorithm>
#include <array>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <stdexcept>
#include <type_traits>

#include "partloc/io/atomic_file.hpp"

namespace partloc::io {

namespace fs = std::filesystem;

namespace {

constexpr char kMagic[16] = "partloc-model-2";  // 15 characters and the terminating zero
constexpr std::size_t kDigest = 32;             // SHA-256
constexpr std::size_t kHeader = sizeof kMagic + 2 * kDigest + 8;

using Digest = std::array<unsigned char, kDigest>;

/// Values copied as bytes: trivially copyable ones, and Eigen's fixed vectors of three (three scalars, no
/// padding; Eigen declares their copy, so they are not trivially copyable to the compiler).
template <class T>
constexpr bool kPlain = std::is_trivially_copyable_v<T> || std::is_same_v<T, Eigen::Vector3d> ||
                        std::is_same_v<T, Eigen::Vector3i>;
static_assert(sizeof(Eigen::Vector3d) == 3 * sizeof(double) && sizeof(Eigen::Vector3i) == 3 * sizeof(int));

Digest sha256(const char* data, std::size_t size) {
    Digest d{};
    unsigned int n = 0;
    if (EVP_Digest(data, size, d.data(), &n, EVP_sha256(), nullptr) != 1 || n != kDigest)
        throw std::runtime_error("SHA-256 failed");
    return d;
}

Digest sha256(const std::string& bytes) { return sha256(bytes.data(), bytes.size()); }

std::string hex(const Digest& d) {
    static const char* digits = "0123456789abcdef";
    std::string s;
    for (unsigned char c : d) {
        s += digits[c >> 4];
        s += digits[c & 15];
    }
    return s;
}

/// Bytes appended in the machine's order: a cache file is read back by the build that wrote it (the build id
/// is in its name), so on the same kind of machine.
class Writer {
  public:
    template <class T>
    void value(const T& v) {
        static_assert(kPlain<T>);
        bytes_.append(reinterpret_cast<const char*>(&v), sizeof v);
    }
    template <class T>
    void array(const std::vector<T>& v) {
        static_assert(kPlain<T>);
        value<std::uint64_t>(v.size());
        bytes_.append(reinterpret_cast<const char*>(v.data()), v.size() * sizeof(T));
    }
    void text(const std::string& s) {
        value<std::uint64_t>(s.size());
        bytes_ += s;
    }
    std::string& bytes() { return bytes_; }

  private:
    std::string bytes_;
};

/// Reads what Writer wrote; throws std::runtime_error past the end.
class Reader {
  public:
    Reader(const char* data, std::size_t size) : at_(data), end_(data + size) {}
    template <class T>
    T value() {
        T v;
        take(&v, sizeof v);
        return v;
    }
    template <class T>
    std::vector<T> array() {
        static_assert(kPlain<T>);
        const auto n = value<std::uint64_t>();
        if (n > static_cast<std::uint64_t>(end_ - at_) / sizeof(T))
            throw std::runtime_error("array past the end");
        std::vector<T> v(n);
        take(v.data(), n * sizeof(T));
        return v;
    }
    bool done() const { return at_ == end_; }

  private:
    void take(void* out, std::size_t n) {
        if (n > static_cast<std::size_t>(end_ - at_)) throw std::runtime_error("truncated");
        std::memcpy(out, at_, n);
        at_ += n;
    }
    const char* at_;
    const char* end_;
};

/// Everything prepare_model's result depends on, hashed: the file's name and the check of its header.
Digest key_of(const open3d::geometry::TriangleMesh* mesh, const open3d::geometry::PointCloud* points,
              double dense_spacing, double sampling) {
    Writer w;
    w.text(kMagic);
    w.text(build_id());
    w.value(dense_spacing);
    w.value(sampling);
    // prepare_model's choice: the mesh when it has triangles, else the points.
    if (mesh && !mesh->triangles_.empty()) {
        w.text("mesh");
        w.array(mesh->vertices_);
        w.array(mesh->triangles_);
        w.array(mesh->vertex_normals_);
        w.array(mesh->triangle_normals_);
    } else if (points && !points->points_.empty()) {
        w.text("points");
        w.array(points->points_);
        w.array(points->normals_);
    } else {
        w.text("none");
    }
    return sha256(w.bytes());
}

void write_frame(Writer& w, const CellFrame& f) {
    w.value(f.origin.x());
    w.value(f.origin.y());
    w.value(f.origin.z());
    w.value(f.cell);
    w.value(f.inv_cell);
    w.value(f.nx);
    w.value(f.ny);
    w.value(f.nz);
}

CellFrame read_frame(Reader& r) {
    CellFrame f;
    f.origin.x() = r.value<double>();
    f.origin.y() = r.value<double>();
    f.origin.z() = r.value<double>();
    f.cell = r.value<double>();
    f.inv_cell = r.value<double>();
    f.nx = r.value<int>();
    f.ny = r.value<int>();
    f.nz = r.value<int>();
    return f;
}

/// The cache file of the model with this key.
fs::path file_of(const fs::path& dir, const Digest& key) { return dir / (hex(key) + ".model"); }

std::string encode(const PreparedModel& m) {
    Writer w;
    w.array(m.dense.cloud->points_);
    w.array(m.dense.cloud->normals_);
    const SampleGrid& g = m.dense.grid;
    write_frame(w, g.frame());
    w.array(g.order());
    w.array(g.starts());
    w.array(g.distances());
    const NearestMap* map = m.dense.coarse.get();
    w.value<std::uint8_t>(map ? 1 : 0);
    if (map) {
        write_frame(w, map->frame());
        w.value(map->reach());
        w.array(map->cells());
    }
    w.array(m.ppf->points());
    w.array(m.ppf->normals());
    w.array(m.ppf->offsets());
    w.array(m.ppf->entries());
    w.value<std::uint64_t>(m.ppf->max_bucket());
    return std::move(w.bytes());
}

/// The model encode() wrote, built as prepare_model builds it; throws when the bytes do not make one.
PreparedModel decode(const char* payload, std::size_t size, const std::string& name, double dense_spacing,
                     double sampling) {
    Reader r(payload, size);
    auto cloud = std::make_shared<open3d::geometry::PointCloud>();
    cloud->points_ = r.array<Eigen::Vector3d>();
    cloud->normals_ = r.array<Eigen::Vector3d>();
    if (cloud->points_.empty() || cloud->normals_.size() != cloud->points_.size())
        throw std::runtime_error("no samples");
    PreparedModel m;
    m.name = name;
    m.sampling = sampling;
    const CellFrame grid_frame = read_frame(r);
    auto order = r.array<std::uint32_t>();
    auto starts = r.array<std::uint32_t>();
    auto distances = r.array<std::uint8_t>();
    m.dense = make_surface(
        cloud, dense_spacing,
        SampleGrid(cloud->points_, grid_frame, std::move(order), std::move(starts), std::move(distances)));
    if (r.value<std::uint8_t>()) {
        const CellFrame f = read_frame(r);
        const auto reach = r.value<double>();
        auto cells = r.array<std::int32_t>();
        m.dense.coarse =
            std::make_shared<const NearestMap>(f, reach, std::move(cells), m.dense.points.size());
    }
    const auto points = r.array<Eigen::Vector3d>();
    const auto normals = r.array<Eigen::Vector3d>();
    auto offsets = r.array<std::uint32_t>();
    auto entries = r.array<PpfModel::Entry>();
    const auto max_bucket = r.value<std::uint64_t>();
    if (!r.done()) throw std::runtime_error("bytes left over");
    PpfSettings ps;
    ps.sampling = sampling;
    m.ppf = std::make_shared<PpfModel>(points, normals, ps, std::move(offsets), std::move(entries),
                                       static_cast<std::size_t>(max_bucket));
    m.symmetry = find_symmetry(m.dense);  // found again, as prepare_model finds it: not stored
    return m;
}

}  // namespace

ModelCache::ModelCache(fs::path dir, std::uintmax_t max_bytes)
    : dir_(std::move(dir)), max_bytes_(max_bytes) {}

fs::path ModelCache::default_dir() {
    const auto env = [](const char* name) -> std::string {
        const char* v = std::getenv(name);
        return v ? v : "";
    };
    if (!env("PARTLOC_CACHE").empty()) return env("PARTLOC_CACHE");
    if (!env("XDG_CACHE_HOME").empty()) return fs::path(env("XDG_CACHE_HOME")) / "partloc";
    if (!env("HOME").empty()) return fs::path(env("HOME")) / ".cache" / "partloc";
    return {};
}

fs::path ModelCache::file_for(const open3d::geometry::TriangleMesh* mesh,
                              const open3d::geometry::PointCloud* points, double dense_spacing,
                              double sampling) const {
    return file_of(dir_, key_of(mesh, points, dense_spacing, sampling));
}

namespace {

/// The model in `file`, written by store() under `key`; throws std::runtime_error saying what is wrong with
/// the file otherwise.
PreparedModel load(const fs::path& file, const Digest& key, const std::string& name, double dense_spacing,
                   double sampling) {
    std::ifstream in(file, std::ios::binary | std::ios::ate);
    const std::streamoff length = in ? static_cast<std::streamoff>(in.tellg()) : -1;
    if (length < 0) throw std::runtime_error("cannot be read");
    std::string bytes(static_cast<std::size_t>(length), '\0');
    in.seekg(0);
    if (!in.read(bytes.data(), length)) throw std::runtime_error("cannot be read");
    if (bytes.size() < kHeader || std::memcmp(bytes.data(), kMagic, sizeof kMagic) != 0)
        throw std::runtime_error("not a model cache file");
    if (std::memcmp(bytes.data() + sizeof kMagic, key.data(), kDigest) != 0)
        throw std::runtime_error("holds another model");
    std::uint64_t size = 0;
    std::memcpy(&size, bytes.data() + sizeof kMagic + 2 * kDigest, sizeof size);
    if (size != bytes.size() - kHeader) throw std::runtime_error("truncated");
    const char* payload = bytes.data() + kHeader;  // read in place: no copy of the megabytes
    if (std::memcmp(bytes.data() + sizeof kMagic + kDigest, sha256(payload, size).data(), kDigest) != 0)
        throw std::runtime_error("damaged (its checksum does not match)");
    return decode(payload, size, name, dense_spacing, sampling);
}

/// Writes model m to `file` (whole or not at all): the header (magic, key, the payload's SHA-256 and size),
/// then the payload. Throws std::runtime_error when it cannot.
void store(const fs::path& file, const Digest& key, const PreparedModel& m) {
    const std::string payload = encode(m);
    const Digest check = sha256(payload);
    std::string bytes(kMagic, sizeof kMagic);
    bytes.append(reinterpret_cast<const char*>(key.data()), kDigest);
    bytes.append(reinterpret_cast<const char*>(check.data()), kDigest);
    const std::uint64_t size = payload.size();
    bytes.append(reinterpret_cast<const char*>(&size), sizeof size);
    bytes += payload;
    write_text_atomically(file, bytes);
}

}  // namespace

PreparedModel ModelCache::prepare(const std::string& name, const open3d::geometry::TriangleMesh* mesh,
                                  const open3d::geometry::PointCloud* points, double dense_spacing,
                                  double sampling) {
    const Digest key = key_of(mesh, points, dense_spacing, sampling);
    const fs::path file = file_of(dir_, key);
    std::error_code ec;
    if (fs::is_regular_file(file, ec)) {
        try {
            PreparedModel m = load(file, key, name, dense_spacing, sampling);
            fs::last_write_time(file, fs::file_time_type::clock::now(), ec);  // used now: trimmed last
            std::lock_guard<std::mutex> lock(mutex_);
            ++hits_;
            return m;
        } catch (const std::exception& e) {
            note(file.string() + ": " + e.what() + "; prepared again");
        }
    }
    PreparedModel m = prepare_model(name, mesh, points, dense_spacing, sampling);
    {
        std::lock_guard<std::mutex> lock(mutex_);
        ++misses_;
    }
    try {
        store(file, key, m);
        trim(file);
    } catch (const std::exception& e) {
        note(std::string("cannot keep ") + name + " in the model cache: " + e.what());
    }
    return m;
}

void ModelCache::trim(const fs::path& keep) {
    std::lock_guard<std::mutex> lock(mutex_);  // one trim at a time
    std::error_code ec;
    struct File {
        fs::path path;
        fs::file_time_type used;
        std::uintmax_t bytes;
    };
    std::vector<File> files;
    std::uintmax_t total = 0;
    for (fs::directory_iterator it(dir_, ec), end; !ec && it != end; it.increment(ec)) {
        if (it->path().extension() != ".model" || !it->is_regular_file(ec)) continue;
        File f{it->path(), it->last_write_time(ec), it->file_size(ec)};
        if (ec) continue;
        total += f.bytes;
        files.push_back(std::move(f));
    }
    if (total <= max_bytes_) return;
    std::sort(files.begin(), files.end(), [](const File& a, const File& b) { return a.used < b.used; });
    for (const File& f : files) {
        if (total <= max_bytes_ / 4 * 3) break;
        if (f.path == keep) continue;
        if (fs::remove(f.path, ec)) total -= f.bytes;
    }
}

void ModelCache::note(std::string problem) {
    std::lock_guard<std::mutex> lock(mutex_);
    problems_.push_back(std::move(problem));
}

std::vector<std::string> ModelCache::problems() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return problems_;
}

std::size_t ModelCache::hits() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return hits_;
}

std::size_t ModelCache::misses() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return misses_;
}

}  // namespace partloc::io
