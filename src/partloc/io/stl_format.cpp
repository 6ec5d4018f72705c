// STL, ascii and binary. Written here rather than through Open3D (which hands STL to Assimp) so that the
// checks are ours: a binary STL whose 80-byte header starts with "solid" (many CAD exports) is told from
// an ascii one by its size, a truncated file is reported with the triangle counts, and the corners every
// facet repeats are merged into shared vertices.
#include <array>
#include <cctype>
#include <cstdint>
#include <cstring>
#include <unordered_map>

#include "partloc/io/formats.hpp"

namespace partloc::io::detail {

namespace {

/// Merges corners with bit-identical coordinates: STL stores each corner once per facet.
class VertexMerger {
  public:
    explicit VertexMerger(RawGeometry& g) : g_(g) {}

    int add(const Eigen::Vector3d& p) {
        std::array<std::uint64_t, 3> key;
        for (int i = 0; i < 3; ++i) {
            const double v = p[i] == 0.0 ? 0.0 : p[i];  // -0 and +0 are one corner
            std::memcpy(&key[i], &v, sizeof v);
        }
        const auto [it, inserted] = index_.try_emplace(key, static_cast<int>(g_.vertices.size()));
        if (inserted) g_.vertices.push_back(p);
        return it->second;
    }

    void triangle(int a, int b, int c) {
        // Two corners the same: the facet bounds no area.
        if (a != b && b != c && a != c) g_.triangles.emplace_back(a, b, c);
    }

  private:
    struct KeyHash {
        std::size_t operator()(const std::array<std::uint64_t, 3>& k) const {
            return std::hash<std::uint64_t>()(k[0] * 73856093u ^ k[1] * 19349663u ^ k[2] * 83492791u);
        }
    };
    RawGeometry& g_;
    std::unordered_map<std::array<std::uint64_t, 3>, int, KeyHash> index_;
};

bool iequals(std::string_view a, const char* b) {
    const std::size_t n = std::strlen(b);
    if (a.size() != n) return false;
    for (std::size_t i = 0; i < n; ++i)
        if (std::tolower(static_cast<unsigned char>(a[i])) != b[i]) return false;
    return true;
}

float load_f32_le(const char* p) {
    unsigned char b[4];
    std::memcpy(b, p, 4);
    const std::uint32_t u = std::uint32_t(b[0]) | std::uint32_t(b[1]) << 8 | std::uint32_t(b[2]) << 16 |
                            std::uint32_t(b[3]) << 24;
    float f;
    std::memcpy(&f, &u, 4);
    return f;
}

std::uint32_t load_u32_le(const char* p) {
    unsigned char b[4];
    std::memcpy(b, p, 4);
    return std::uint32_t(b[0]) | std::uint32_t(b[1]) << 8 | std::uint32_t(b[2]) << 16 |
           std::uint32_t(b[3]) << 24;
}

RawGeometry parse_binary(std::string_view bytes, std::uint64_t count) {
    RawGeometry g;
    g.vertices.reserve(count / 2 + 3);
    g.triangles.reserve(count);
    VertexMerger merge(g);
    for (std::uint64_t t = 0; t < count; ++t) {
        const char* facet = bytes.data() + 84 + 50 * t;
        int corner[3];
        for (int c = 0; c < 3; ++c) {
            const char* v = facet + 12 + 12 * c;  // after the facet normal
            corner[c] = merge.add(Eigen::Vector3d(load_f32_le(v), load_f32_le(v + 4), load_f32_le(v + 8)));
        }
        merge.triangle(corner[0], corner[1], corner[2]);
    }
    return g;
}

RawGeometry parse_ascii(std::string_view bytes, const std::string& name) {
    RawGeometry g;
    VertexMerger merge(g);
    TokenReader tokens(bytes);
    std::string_view t;
    const auto fail = [&](const std::string& what) {
        return InputError(name, "line " + std::to_string(tokens.line()) + ": " + what);
    };
    const auto expect = [&](const char* word) {
        if (!tokens.next(t)) throw InputError(name, "file is truncated (inside a facet)");
        if (!iequals(t, word))
            throw fail(std::string("expected '") + word + "', found '" + std::string(t.substr(0, 40)) + "'");
    };
    const auto number = [&]() {
        double v = 0;
        if (!tokens.next(t)) throw InputError(name, "file is truncated (inside a facet)");
        if (!parse_number(t, v))
            throw fail("expected a number, found '" + std::string(t.substr(0, 40)) + "'");
        return v;
    };

    bool in_solid = false;
    std::size_t facets = 0;
    std::vector<int> polygon;
    // Between facets only solid names may appear; they are any words, so words there are skipped.
    while (tokens.next(t)) {
        if (iequals(t, "solid")) {
            in_solid = true;
        } else if (iequals(t, "endsolid")) {
            in_solid = false;
        } else if (iequals(t, "facet")) {
            if (!in_solid) throw fail("'facet' outside 'solid ... endsolid'");
            expect("normal");
            number(), number(), number();
            expect("outer");
            expect("loop");
            polygon.clear();
            while (true) {
                if (!tokens.next(t)) throw InputError(name, "file is truncated (inside a facet)");
                if (iequals(t, "endloop")) break;
                if (!iequals(t, "vertex"))
                    throw fail("expected 'vertex' or 'endloop', found '" + std::string(t.substr(0, 40)) +
                               "'");
                const double x = number(), y = number(), z = number();
                polygon.push_back(merge.add(Eigen::Vector3d(x, y, z)));
            }
            expect("endfacet");
            if (polygon.size() < 3) throw fail("facet with fewer than 3 vertices");
            for (std::size_t j = 1; j + 1 < polygon.size(); ++j)
                merge.triangle(polygon[0], polygon[j], polygon[j + 1]);
            ++facets;
        }
    }
    if (in_solid)
        throw InputError(name,
                         "file is truncated (no 'endsolid' after " + std::to_string(facets) + " facets)");
    return g;
}

}  // namespace

RawGeometry parse_stl(std::string_view bytes, const std::string& name) {
    const std::uint64_t size = bytes.size();
    const std::uint64_t count = size >= 84 ? load_u32_le(bytes.data() + 80) : 0;
    const std::uint64_t expected = 84 + 50 * count;
    if (size >= 84 && size == expected) return parse_binary(bytes, count);

    std::size_t first = 0;
    while (first < bytes.size() && std::isspace(static_cast<unsigned char>(bytes[first]))) ++first;
    if (iequals(bytes.substr(first, 5), "solid") && !looks_binary(bytes)) return parse_ascii(bytes, name);

    if (size < 84) throw InputError(name, "too short to be an STL file (" + std::to_string(size) + " bytes)");
    // Some exporters pad binary files; extra bytes after the last facet are harmless.
    if (size > expected) return parse_binary(bytes, count);
    throw InputError(name, "file is truncated (expected " + std::to_string(count) + " triangles, found " +
                               std::to_string((size - 84) / 50) + ")");
}

}  // namespace partloc::io::detail
