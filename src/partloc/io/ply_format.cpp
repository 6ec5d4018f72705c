// PLY, ascii and binary (http://paulbourke.net/dataformats/ply/). Written here rather than through Open3D
// because Open3D's reader (RPly) prints to stderr on its own and, on a truncated file, returns the points it
// got plus zeros for the rest. Elements other than vertex and face (the Stanford bunny's range_grid, say)
// are read past, so a file truncated inside them is still reported.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>

#include "partloc/io/formats.hpp"

namespace partloc::io::detail {

namespace {

enum class PlyType { Int8, UInt8, Int16, UInt16, Int32, UInt32, Float32, Float64 };
enum class PlyEncoding { Ascii, BinaryLittleEndian, BinaryBigEndian };

struct PlyProperty {
    std::string name;
    PlyType type = PlyType::Float32;
    bool is_list = false;
    PlyType count_type = PlyType::UInt8;
};

struct PlyElement {
    std::string name;
    std::size_t count = 0;
    std::vector<PlyProperty> properties;
};

bool type_from_name(const std::string& s, PlyType& t) {
    static const std::pair<const char*, PlyType> names[] = {
        {"char", PlyType::Int8},      {"int8", PlyType::Int8},       {"uchar", PlyType::UInt8},
        {"uint8", PlyType::UInt8},    {"short", PlyType::Int16},     {"int16", PlyType::Int16},
        {"ushort", PlyType::UInt16},  {"uint16", PlyType::UInt16},   {"int", PlyType::Int32},
        {"int32", PlyType::Int32},    {"uint", PlyType::UInt32},     {"uint32", PlyType::UInt32},
        {"float", PlyType::Float32},  {"float32", PlyType::Float32}, {"double", PlyType::Float64},
        {"float64", PlyType::Float64}};
    for (const auto& [n, type] : names)
        if (s == n) {
            t = type;
            return true;
        }
    return false;
}

std::size_t size_of(PlyType t) {
    switch (t) {
        case PlyType::Int8:
        case PlyType::UInt8:
            return 1;
        case PlyType::Int16:
        case PlyType::UInt16:
            return 2;
        case PlyType::Int32:
        case PlyType::UInt32:
        case PlyType::Float32:
            return 4;
        case PlyType::Float64:
            return 8;
    }
    return 0;
}

bool is_integer(PlyType t) { return t != PlyType::Float32 && t != PlyType::Float64; }

bool host_is_little_endian() {
    const std::uint16_t one = 1;
    unsigned char first;
    std::memcpy(&first, &one, 1);
    return first == 1;
}

template <typename T>
T load(const unsigned char* p, bool swap) {
    unsigned char b[sizeof(T)];
    std::memcpy(b, p, sizeof(T));
    if (swap)
        for (std::size_t i = 0; i < sizeof(T) / 2; ++i) std::swap(b[i], b[sizeof(T) - 1 - i]);
    T v;
    std::memcpy(&v, b, sizeof(T));
    return v;
}

/// A binary value of type t at p (single bytes are never swapped): next() and the fixed-size vertex reader.
double load_value(PlyType t, const unsigned char* p, bool swap) {
    switch (t) {
        case PlyType::Int8:
            return load<std::int8_t>(p, false);
        case PlyType::UInt8:
            return load<std::uint8_t>(p, false);
        case PlyType::Int16:
            return load<std::int16_t>(p, swap);
        case PlyType::UInt16:
            return load<std::uint16_t>(p, swap);
        case PlyType::Int32:
            return load<std::int32_t>(p, swap);
        case PlyType::UInt32:
            return load<std::uint32_t>(p, swap);
        case PlyType::Float32:
            return load<float>(p, swap);
        case PlyType::Float64:
            return load<double>(p, swap);
    }
    return 0.0;
}

/// Reads values of the body one at a time, in either encoding. next() returns false at the end of the data.
class PlyBody {
  public:
    PlyBody(std::string_view body, PlyEncoding encoding, std::size_t first_line, const std::string& name)
        : encoding_(encoding),
          p_(reinterpret_cast<const unsigned char*>(body.data())),
          end_(p_ + body.size()),
          tokens_(body, first_line),
          name_(name) {
        swap_ = (encoding == PlyEncoding::BinaryBigEndian) == host_is_little_endian();
    }

    bool next(PlyType t, double& v, const char* what) {
        if (encoding_ == PlyEncoding::Ascii) {
            std::string_view token;
            if (!tokens_.next(token)) return false;
            if (!parse_number(token, v))
                throw InputError(name_, "line " + std::to_string(tokens_.line()) +
                                            ": expected a number for '" + what + "', found '" +
                                            std::string(token.substr(0, 40)) + "'");
            return true;
        }
        const std::size_t n = size_of(t);
        if (static_cast<std::size_t>(end_ - p_) < n) return false;
        v = load_value(t, p_, swap_);
        p_ += n;
        return true;
    }

    /// Skips `count` elements of fixed size `stride` bytes (binary only); false when the data ends first.
    bool skip_fixed(std::size_t count, std::size_t stride, std::size_t& complete) {
        const std::size_t available = static_cast<std::size_t>(end_ - p_) / stride;
        complete = std::min(count, available);
        p_ += complete * stride;
        return complete == count;
    }

    bool binary() const { return encoding_ != PlyEncoding::Ascii; }
    /// True when data is left after the last element: bytes (binary) or a token (ascii).
    bool has_more() {
        if (encoding_ != PlyEncoding::Ascii) return p_ < end_;
        std::string_view token;
        return tokens_.next(token);
    }
    bool swapped() const { return swap_; }
    /// The next `count` records of `stride` bytes (binary only), as far as the data holds whole ones: their
    /// first byte, and how many there are in `complete`; the body moves past them.
    const unsigned char* take_fixed(std::size_t count, std::size_t stride, std::size_t& complete) {
        const unsigned char* at = p_;
        skip_fixed(count, stride, complete);
        return at;
    }

  private:
    PlyEncoding encoding_;
    const unsigned char* p_;
    const unsigned char* end_;
    bool swap_ = false;
    TokenReader tokens_;
    const std::string& name_;
};

std::vector<std::string> words(std::string_view line) {
    std::vector<std::string> out;
    TokenReader r(line);
    std::string_view t;
    while (r.next(t)) out.emplace_back(t);
    return out;
}

int find_property(const PlyElement& e, std::initializer_list<const char*> names) {
    for (std::size_t i = 0; i < e.properties.size(); ++i)
        for (const char* n : names)
            if (e.properties[i].name == n && !e.properties[i].is_list) return static_cast<int>(i);
    return -1;
}

}  // namespace

/// A PLY header after its first line: the encoding and the elements with their properties.
struct PlyHeader {
    PlyEncoding encoding = PlyEncoding::Ascii;
    std::vector<PlyElement> elements;
};

PlyHeader parse_ply_header(LineReader& lines, const std::string& name) {
    std::string_view line;
    PlyEncoding encoding = PlyEncoding::Ascii;
    bool have_format = false, have_end = false;
    std::vector<PlyElement> elements;
    while (lines.next(line)) {
        const std::vector<std::string> w = words(line);
        const std::string at = "header line " + std::to_string(lines.line_number()) + ": ";
        if (w.empty() || w[0] == "comment" || w[0] == "obj_info") continue;
        if (w[0] == "end_header") {
            have_end = true;
            break;
        }
        if (w[0] == "format") {
            if (w.size() < 2) throw InputError(name, at + "format line without a format");
            if (w[1] == "ascii")
                encoding = PlyEncoding::Ascii;
            else if (w[1] == "binary_little_endian")
                encoding = PlyEncoding::BinaryLittleEndian;
            else if (w[1] == "binary_big_endian")
                encoding = PlyEncoding::BinaryBigEndian;
            else
                throw InputError(name, at + "unknown format '" + w[1] + "'");
            have_format = true;
        } else if (w[0] == "element") {
            double count = 0;
            if (w.size() != 3 || !parse_number(w[2], count) || count < 0 || count > 1e12 ||
                count != std::floor(count))
                throw InputError(name, at + "expected 'element NAME COUNT'");
            elements.push_back({w[1], static_cast<std::size_t>(count), {}});
        } else if (w[0] == "property") {
            if (elements.empty()) throw InputError(name, at + "property before any element");
            PlyProperty p;
            if (w.size() == 5 && w[1] == "list") {
                p.is_list = true;
                if (!type_from_name(w[2], p.count_type) || !is_integer(p.count_type) ||
                    !type_from_name(w[3], p.type))
                    throw InputError(name, at + "unknown list types '" + w[2] + " " + w[3] + "'");
                p.name = w[4];
            } else if (w.size() == 3) {
                if (!type_from_name(w[1], p.type)) throw InputError(name, at + "unknown type '" + w[1] + "'");
                p.name = w[2];
            } else {
                throw InputError(name,
                                 at + "expected 'property TYPE NAME' or 'property list TYPE TYPE NAME'");
            }
            elements.back().properties.push_back(p);
        } else {
            throw InputError(name, at + "unknown keyword '" + w[0].substr(0, 40) + "'");
        }
    }
    if (!have_end) throw InputError(name, "PLY header has no end_header (the file is truncated or not PLY)");
    if (!have_format) throw InputError(name, "PLY header has no format line");
    return {encoding, std::move(elements)};
}

RawGeometry parse_ply(std::string_view bytes, const std::string& name) {
    LineReader lines(bytes);
    std::string_view line;
    if (!lines.next(line) || line != "ply")
        throw InputError(name, "not a PLY file (it does not start with 'ply')");

    const PlyHeader header = parse_ply_header(lines, name);
    const PlyEncoding encoding = header.encoding;
    const std::vector<PlyElement>& elements = header.elements;

    RawGeometry g;
    bool have_vertices = false;
    std::size_t vertex_count = 0;
    PlyBody body(bytes.substr(lines.offset() <= bytes.size() ? lines.offset() : bytes.size()), encoding,
                 lines.line_number() + 1, name);

    for (const PlyElement& e : elements) {
        const auto truncated = [&](std::size_t found) {
            return InputError(name, "file is truncated (expected " + std::to_string(e.count) + " " +
                                        plural_of(e.name) + ", found " + std::to_string(found) + ")");
        };
        const bool is_vertex = e.name == "vertex" && !have_vertices;
        const bool is_face = e.name == "face";
        int xyz[3] = {-1, -1, -1}, nxyz[3] = {-1, -1, -1}, indices = -1;
        if (is_vertex) {
            xyz[0] = find_property(e, {"x"});
            xyz[1] = find_property(e, {"y"});
            xyz[2] = find_property(e, {"z"});
            if (xyz[0] < 0 || xyz[1] < 0 || xyz[2] < 0)
                throw InputError(name, "vertex element has no x, y and z properties");
            nxyz[0] = find_property(e, {"nx", "normal_x"});
            nxyz[1] = find_property(e, {"ny", "normal_y"});
            nxyz[2] = find_property(e, {"nz", "normal_z"});
            have_vertices = true;
            vertex_count = e.count;
        }
        if (is_face) {
            for (std::size_t i = 0; i < e.properties.size(); ++i)
                if (e.properties[i].is_list &&
                    (e.properties[i].name == "vertex_indices" || e.properties[i].name == "vertex_index"))
                    indices = static_cast<int>(i);
            if (indices < 0) throw InputError(name, "face element has no vertex_indices list");
        }
        const bool has_normals = nxyz[0] >= 0 && nxyz[1] >= 0 && nxyz[2] >= 0;
        // An element without properties holds no bytes, whatever its count (10^12 of them took minutes to
        // walk). Every other record takes at least a byte, so no loop below outlives the file, and nothing is
        // reserved beyond what the bytes could hold: a lying count costs no more than the file's size.
        if (e.properties.empty()) continue;

        // Records of a fixed size (no lists): their size, and each property's offset in them.
        bool no_lists = true;
        std::size_t stride = 0;
        std::vector<std::size_t> offset;
        for (const auto& p : e.properties) {
            no_lists = no_lists && !p.is_list;
            offset.push_back(stride);
            stride += size_of(p.type);
        }
        const bool fixed = body.binary() && no_lists && stride > 0;
        // Elements that are not used and have a fixed size are skipped whole in binary files.
        if (fixed && !is_vertex && !is_face) {
            std::size_t complete = 0;
            if (!body.skip_fixed(e.count, stride, complete)) throw truncated(complete);
            continue;
        }

        // Binary vertices of fixed size (a scan's usual form): read record by record at the properties'
        // offsets, without a call per value (six scans of 220 k points took 51 ms to load on 2 threads,
        // most of it here).
        if (fixed && is_vertex) {
            std::size_t complete = 0;
            const unsigned char* at = body.take_fixed(e.count, stride, complete);
            const bool swap = body.swapped();
            const auto value = [&](const unsigned char* record, int k) {
                return load_value(e.properties[k].type, record + offset[k], swap);
            };
            g.vertices.resize(complete);
            if (has_normals) g.normals.resize(complete);
            for (std::size_t i = 0; i < complete; ++i) {
                const unsigned char* record = at + i * stride;
                g.vertices[i] =
                    Eigen::Vector3d(value(record, xyz[0]), value(record, xyz[1]), value(record, xyz[2]));
                if (has_normals)
                    g.normals[i] = Eigen::Vector3d(value(record, nxyz[0]), value(record, nxyz[1]),
                                                   value(record, nxyz[2]));
            }
            if (complete < e.count) throw truncated(complete);
            continue;
        }

        // The header's count may be a lie; do not reserve more than the bytes could hold.
        const std::size_t reservable = std::min<std::size_t>(e.count, bytes.size() / 2);
        if (is_vertex) {
            g.vertices.reserve(reservable);
            if (has_normals) g.normals.reserve(reservable);
        }
        if (is_face) g.triangles.reserve(reservable);

        std::vector<double> values(e.properties.size());
        std::vector<int> polygon;
        for (std::size_t i = 0; i < e.count; ++i) {
            for (std::size_t k = 0; k < e.properties.size(); ++k) {
                const PlyProperty& p = e.properties[k];
                if (!p.is_list) {
                    if (!body.next(p.type, values[k], p.name.c_str())) throw truncated(i);
                    continue;
                }
                double n = 0;
                if (!body.next(p.count_type, n, p.name.c_str())) throw truncated(i);
                if (n < 0 || n > 1e9 || n != std::floor(n))
                    throw InputError(
                        name, e.name + " " + std::to_string(i) + ": list '" + p.name + "' has a bad length");
                const bool keep = is_face && static_cast<int>(k) == indices;
                if (keep) polygon.clear();
                for (std::size_t j = 0; j < static_cast<std::size_t>(n); ++j) {
                    double v = 0;
                    if (!body.next(p.type, v, p.name.c_str())) throw truncated(i);
                    if (keep) {
                        if (v < 0 || v != std::floor(v) || v > std::numeric_limits<int>::max())
                            throw InputError(name, "face " + std::to_string(i) + " has a bad vertex index");
                        polygon.push_back(static_cast<int>(v));
                    }
                }
                // A polygon is split into a fan of triangles; fewer than 3 corners bound no area.
                if (keep)
                    for (std::size_t j = 1; j + 1 < polygon.size(); ++j)
                        g.triangles.emplace_back(polygon[0], polygon[j], polygon[j + 1]);
            }
            if (is_vertex) {
                g.vertices.emplace_back(values[xyz[0]], values[xyz[1]], values[xyz[2]]);
                if (has_normals) g.normals.emplace_back(values[nxyz[0]], values[nxyz[1]], values[nxyz[2]]);
            }
        }
    }
    if (!have_vertices) throw InputError(name, "PLY file has no vertex element");
    if (body.has_more())
        g.warnings.push_back("data continues after the header's " + std::to_string(vertex_count) +
                             " vertices and the elements after them; the rest of the file was not read "
                             "(a count smaller than the data: is the file cut or half exported?)");
    for (std::size_t i = 0; i < g.triangles.size(); ++i)
        if (static_cast<std::size_t>(g.triangles[i].maxCoeff()) >= vertex_count)
            throw InputError(name, "a face refers to vertex " + std::to_string(g.triangles[i].maxCoeff()) +
                                       " but the file has " + std::to_string(vertex_count) + " vertices");
    return g;
}

}  // namespace partloc::io::detail
