// Wavefront OBJ: `v` lines and `f` lines; everything else (normals, texture coordinates, groups,
// materials) is not needed for fitting and is read past. Written here because Open3D 0.16 (through Assimp,
// without post-processing) drops polygons with more than three corners without a word, and returns a
// triangle for a face line cut short.
#include <charconv>

#include "partloc/io/formats.hpp"

namespace partloc::io::detail {

RawGeometry parse_obj(std::string_view bytes, const std::string& name) {
    if (looks_binary(bytes)) throw InputError(name, "not an OBJ file (it holds binary data)");
    RawGeometry g;
    LineReader lines(bytes);
    std::string_view line;
    std::vector<int> polygon;
    std::vector<std::string_view> w;
    while (lines.next(line)) {
        const auto at = [&]() { return "line " + std::to_string(lines.line_number()) + ": "; };
        w.clear();
        TokenReader tokens(line);
        std::string_view t;
        while (tokens.next(t)) w.push_back(t);
        if (w.empty() || w[0][0] == '#') continue;
        if (w[0] == "v") {
            // x y z, then an optional w or r g b, which are not used.
            double xyz[3];
            if (w.size() < 4) throw InputError(name, at() + "a vertex needs 3 coordinates");
            for (int i = 0; i < 3; ++i)
                if (!parse_number(w[i + 1], xyz[i]))
                    throw InputError(name,
                                     at() + "'" + std::string(w[i + 1].substr(0, 40)) + "' is not a number");
            g.vertices.emplace_back(xyz[0], xyz[1], xyz[2]);
        } else if (w[0] == "f") {
            if (w.size() < 4) throw InputError(name, at() + "a face needs at least 3 vertices");
            polygon.clear();
            for (std::size_t i = 1; i < w.size(); ++i) {
                // v, v/vt, v//vn or v/vt/vn; 1-based, negative counts back from the last vertex so far.
                const std::string_view ref = w[i].substr(0, w[i].find('/'));
                long index = 0;
                const auto [ptr, ec] = std::from_chars(ref.data(), ref.data() + ref.size(), index);
                if (ec != std::errc() || ptr != ref.data() + ref.size() || index == 0)
                    throw InputError(
                        name, at() + "'" + std::string(w[i].substr(0, 40)) + "' is not a vertex reference");
                const long n = static_cast<long>(g.vertices.size());
                const long zero_based = index > 0 ? index - 1 : n + index;
                if (zero_based < 0 || zero_based >= n)
                    throw InputError(name, at() + "face refers to vertex " + std::to_string(index) + " but " +
                                               std::to_string(n) + " vertices are defined before it");
                polygon.push_back(static_cast<int>(zero_based));
            }
            for (std::size_t j = 1; j + 1 < polygon.size(); ++j)
                g.triangles.emplace_back(polygon[0], polygon[j], polygon[j + 1]);
        }
    }
    return g;
}

}  // namespace partloc::io::detail
