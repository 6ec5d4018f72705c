// PCD (https://pointclouds.org/documentation/tutorials/pcd_file_format.html). The header is checked here
// against the file's size, because Open3D, given a truncated ascii PCD, reports success with made-up points
// at the end. ascii data is parsed here; binary and binary_compressed (LZF) data, once their size is known
// to match the header, are decoded by Open3D.
#include <open3d/io/PointCloudIO.h>
#include <open3d/utility/Logging.h>

#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <mutex>

#include "partloc/io/formats.hpp"

namespace partloc::io::detail {

namespace {

/// Open3D logs warnings to stdout from inside its readers; library code must not print. The level is
/// process-wide, so readers running in parallel share one silenced span.
class QuietOpen3D {
  public:
    QuietOpen3D() {
        std::lock_guard<std::mutex> lock(mutex());
        if (depth()++ == 0) {
            saved() = open3d::utility::GetVerbosityLevel();
            open3d::utility::SetVerbosityLevel(open3d::utility::VerbosityLevel::Error);
        }
    }
    ~QuietOpen3D() {
        std::lock_guard<std::mutex> lock(mutex());
        if (--depth() == 0) open3d::utility::SetVerbosityLevel(saved());
    }
    QuietOpen3D(const QuietOpen3D&) = delete;
    QuietOpen3D& operator=(const QuietOpen3D&) = delete;

  private:
    static std::mutex& mutex() {
        static std::mutex m;
        return m;
    }
    static int& depth() {
        static int d = 0;
        return d;
    }
    static open3d::utility::VerbosityLevel& saved() {
        static open3d::utility::VerbosityLevel level = open3d::utility::VerbosityLevel::Info;
        return level;
    }
};

struct PcdHeader {
    std::vector<std::string> fields;
    std::vector<std::size_t> sizes, counts;
    std::size_t points = 0;
    std::string data;                  ///< ascii, binary or binary_compressed
    std::size_t data_offset = 0;       ///< first byte after the DATA line
    std::size_t data_line = 0;         ///< line number of the DATA line
    std::size_t point_bytes = 0;       ///< sum of size * count
    std::size_t values_per_point = 0;  ///< sum of count

    int offset_of(const std::string& field) const {  // in values, for ascii rows
        std::size_t offset = 0;
        for (std::size_t i = 0; i < fields.size(); ++i) {
            if (fields[i] == field) return static_cast<int>(offset);
            offset += counts[i];
        }
        return -1;
    }
};

PcdHeader parse_header(std::string_view bytes, const std::string& name) {
    PcdHeader h;
    LineReader lines(bytes);
    std::string_view line;
    std::vector<std::string_view> types;
    std::size_t width = 0, height = 0;
    bool have_points = false, have_width = false;
    while (lines.next(line)) {
        std::vector<std::string_view> w;
        TokenReader tokens(line);
        std::string_view t;
        while (tokens.next(t)) w.push_back(t);
        if (w.empty() || w[0][0] == '#') continue;
        const std::string at = "header line " + std::to_string(lines.line_number()) + ": ";
        const auto unsigned_at = [&](std::size_t i) {
            double v = 0;
            if (i >= w.size() || !parse_number(w[i], v) || v < 0 || v > 1e12 || v != std::floor(v))
                throw InputError(name, at + "expected a whole number after " + std::string(w[0]));
            return static_cast<std::size_t>(v);
        };
        if (w[0] == "VERSION" || w[0] == "VIEWPOINT") {
        } else if (w[0] == "FIELDS") {
            for (std::size_t i = 1; i < w.size(); ++i) h.fields.emplace_back(w[i]);
        } else if (w[0] == "SIZE") {
            for (std::size_t i = 1; i < w.size(); ++i) h.sizes.push_back(unsigned_at(i));
        } else if (w[0] == "TYPE") {
            types.assign(w.begin() + 1, w.end());
        } else if (w[0] == "COUNT") {
            for (std::size_t i = 1; i < w.size(); ++i) h.counts.push_back(unsigned_at(i));
        } else if (w[0] == "WIDTH") {
            width = unsigned_at(1);
            have_width = true;
        } else if (w[0] == "HEIGHT") {
            height = unsigned_at(1);
        } else if (w[0] == "POINTS") {
            h.points = unsigned_at(1);
            have_points = true;
        } else if (w[0] == "DATA") {
            if (w.size() < 2) throw InputError(name, at + "DATA without a kind");
            h.data = std::string(w[1]);
            h.data_offset = std::min(lines.offset(), bytes.size());
            h.data_line = lines.line_number();
            break;
        } else {
            throw InputError(
                name, at + "unknown keyword '" + std::string(w[0].substr(0, 40)) + "' (not a PCD file?)");
        }
    }
    if (h.data.empty())
        throw InputError(name, "PCD header has no DATA line (the file is truncated or not PCD)");
    if (h.data != "ascii" && h.data != "binary" && h.data != "binary_compressed")
        throw InputError(name, "unknown PCD DATA kind '" + h.data + "'");
    if (h.counts.empty()) h.counts.assign(h.fields.size(), 1);
    if (h.fields.empty() || h.sizes.size() != h.fields.size() || types.size() != h.fields.size() ||
        h.counts.size() != h.fields.size())
        throw InputError(name, "PCD header: FIELDS, SIZE, TYPE and COUNT do not have the same length");
    if (h.offset_of("x") < 0 || h.offset_of("y") < 0 || h.offset_of("z") < 0)
        throw InputError(name, "PCD header: no x, y and z fields");
    if (!have_points) {
        if (!have_width) throw InputError(name, "PCD header: neither POINTS nor WIDTH");
        h.points = width * std::max<std::size_t>(height, 1);
    }
    // Every count is checked against the file's size before it sizes anything: a header may ask 10^12
    // values per point (the ascii reader's row of values, 8 TB), or points of terabytes, in a file of a few
    // hundred bytes, and the products below would overflow. The number of points needs no check here: the
    // ascii reader reserves no more than the bytes hold, and the binary size check follows.
    const long double data_bytes = static_cast<long double>(bytes.size() - h.data_offset);
    long double point_bytes = 0, values = 0;
    for (std::size_t i = 0; i < h.fields.size(); ++i) {
        point_bytes += static_cast<long double>(h.sizes[i]) * h.counts[i];
        values += h.counts[i];
    }
    if (h.points > 0 && values > data_bytes + 1)
        throw InputError(name, "file is truncated (the header's points of " +
                                   std::to_string(static_cast<unsigned long long>(values)) +
                                   " values each need more data than the file's " +
                                   std::to_string(bytes.size() - h.data_offset) + " bytes)");
    if (point_bytes > static_cast<long double>(std::numeric_limits<std::uint32_t>::max()) ||
        static_cast<long double>(h.points) * point_bytes > 1e15L)
        throw InputError(name, "PCD header: points of " +
                                   std::to_string(static_cast<unsigned long long>(point_bytes)) +
                                   " bytes each are more than any file holds");
    for (std::size_t i = 0; i < h.fields.size(); ++i) {
        h.point_bytes += h.sizes[i] * h.counts[i];
        h.values_per_point += h.counts[i];
    }
    return h;
}

RawGeometry parse_ascii(std::string_view bytes, const PcdHeader& h, const std::string& name) {
    RawGeometry g;
    const int ox = h.offset_of("x"), oy = h.offset_of("y"), oz = h.offset_of("z");
    const int onx = h.offset_of("normal_x"), ony = h.offset_of("normal_y"), onz = h.offset_of("normal_z");
    const bool normals = onx >= 0 && ony >= 0 && onz >= 0;
    g.vertices.reserve(std::min(h.points, bytes.size() / 6));
    const std::string_view data = bytes.substr(h.data_offset);
    LineReader lines(data);
    std::string_view line;
    std::vector<std::string_view> cells;
    std::vector<double> values(h.values_per_point);
    while (lines.next(line)) {
        const std::string at = "line " + std::to_string(h.data_line + lines.line_number()) + ": ";
        cells.clear();
        TokenReader tokens(line);
        std::string_view t;
        while (tokens.next(t)) cells.push_back(t);
        if (cells.empty()) continue;
        if (g.vertices.size() == h.points)
            throw InputError(
                name, at + "more data lines than the header's " + std::to_string(h.points) + " points");
        if (cells.size() != h.values_per_point) {
            const bool cut_short = lines.offset() > data.size() && cells.size() < h.values_per_point;
            if (cut_short) break;  // reported as truncated below
            throw InputError(name, at + "expected " + std::to_string(h.values_per_point) + " values, found " +
                                       std::to_string(cells.size()));
        }
        for (std::size_t k = 0; k < cells.size(); ++k)
            if (!parse_number(cells[k], values[k]))
                throw InputError(name, at + "'" + std::string(cells[k].substr(0, 40)) + "' is not a number");
        g.vertices.emplace_back(values[ox], values[oy], values[oz]);
        if (normals) g.normals.emplace_back(values[onx], values[ony], values[onz]);
    }
    if (g.vertices.size() != h.points)
        throw InputError(name, "file is truncated (expected " + std::to_string(h.points) + " points, found " +
                                   std::to_string(g.vertices.size()) + ")");
    return g;
}

std::uint32_t load_u32_le(const char* p) {
    unsigned char b[4];
    std::memcpy(b, p, 4);
    return std::uint32_t(b[0]) | std::uint32_t(b[1]) << 8 | std::uint32_t(b[2]) << 16 |
           std::uint32_t(b[3]) << 24;
}

}  // namespace

RawGeometry read_pcd(const std::filesystem::path& path, std::string_view bytes, const std::string& name) {
    const PcdHeader h = parse_header(bytes, name);
    if (h.data == "ascii") return parse_ascii(bytes, h, name);

    const std::size_t available = bytes.size() - h.data_offset;
    std::string extra;
    if (h.data == "binary") {
        if (h.point_bytes == 0) throw InputError(name, "PCD header: points of 0 bytes");
        if (available < h.points * h.point_bytes)
            throw InputError(name, "file is truncated (expected " + std::to_string(h.points) +
                                       " points, found " + std::to_string(available / h.point_bytes) + ")");
        if (available > h.points * h.point_bytes)
            extra = "the data holds " + std::to_string(available - h.points * h.point_bytes) +
                    " bytes more than the header's " + std::to_string(h.points) + " points";
    } else {
        // binary_compressed: uint32 compressed size, uint32 uncompressed size, then the LZF block.
        if (available < 8) throw InputError(name, "file is truncated (no compressed data after the header)");
        const std::size_t compressed = load_u32_le(bytes.data() + h.data_offset);
        const std::size_t uncompressed = load_u32_le(bytes.data() + h.data_offset + 4);
        if (available - 8 < compressed)
            throw InputError(name, "file is truncated (expected " + std::to_string(compressed) +
                                       " bytes of compressed data, found " + std::to_string(available - 8) +
                                       ")");
        if (uncompressed != h.points * h.point_bytes)
            throw InputError(name, "compressed data holds " + std::to_string(uncompressed) +
                                       " bytes but the header's " + std::to_string(h.points) +
                                       " points need " + std::to_string(h.points * h.point_bytes));
    }

    open3d::geometry::PointCloud cloud;
    bool ok = false;
    {
        QuietOpen3D quiet;
        try {
            ok = open3d::io::ReadPointCloud(path.string(), cloud, open3d::io::ReadPointCloudOption("pcd"));
        } catch (const std::exception& e) {
            throw InputError(name, std::string("PCD data cannot be decoded (") + e.what() + ")");
        }
    }
    if (!ok || cloud.points_.size() != h.points)
        throw InputError(name, "PCD " + h.data + " data cannot be decoded (the file is corrupt)");
    RawGeometry g;
    g.vertices = std::move(cloud.points_);
    if (cloud.normals_.size() == g.vertices.size()) g.normals = std::move(cloud.normals_);
    if (!extra.empty())
        g.warnings.push_back(extra +
                             "; the rest of the file was not read (a count smaller than the data: is "
                             "the file cut or half exported?)");
    return g;
}

}  // namespace partloc::io::detail
