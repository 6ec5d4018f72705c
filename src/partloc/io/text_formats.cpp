// Plain-text clouds: columns (.xyz .txt .csv) and legacy VTK. Written here because Open3D's XYZ reader
// skips lines it cannot parse and reports success on a file of garbage (an empty cloud), and has no CSV or
// VTK reader.
#include <algorithm>
#include <cctype>
#include <cmath>

#include "partloc/io/formats.hpp"

namespace partloc::io::detail {

namespace {

std::string normalised_column_name(std::string_view s) {
    std::string out;
    for (char c : s)
        if (c != '"' && c != '\'') out += static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
    return out;
}

int column_named(const std::vector<std::string>& names, std::initializer_list<const char*> candidates) {
    for (std::size_t i = 0; i < names.size(); ++i)
        for (const char* c : candidates)
            if (names[i] == c) return static_cast<int>(i);
    return -1;
}

std::string_view unquoted(std::string_view s) {
    if (s.size() >= 2 && s.front() == '"' && s.back() == '"') return s.substr(1, s.size() - 2);
    return s;
}

}  // namespace

RawGeometry parse_columns(std::string_view bytes, const std::string& name) {
    if (looks_binary(bytes)) throw InputError(name, "not a text file (it holds binary data)");
    RawGeometry g;
    LineReader lines(bytes);
    std::string_view line;
    std::size_t columns = 0;  // of every data line; 0 until the first one
    int ix = 0, iy = 1, iz = 2, inx = -1, iny = -1, inz = -1;
    bool have_header = false, named_normals = false;
    std::vector<Eigen::Vector3d> maybe_normals;  // columns 4-6 of a file without a header
    std::vector<double> row;

    while (lines.next(line)) {
        std::size_t first = line.find_first_not_of(" \t");
        if (first == std::string_view::npos) continue;
        std::string_view content = line.substr(first);
        const bool slashes = content.substr(0, 2) == "//";  // CloudCompare writes its header as "//X,Y,Z"
        if (content[0] == '#' || (slashes && (have_header || columns > 0))) continue;
        if (slashes) content.remove_prefix(2);
        const std::vector<std::string_view> cells = split_columns(content);
        if (cells.empty()) continue;

        row.resize(cells.size());
        bool numeric = true;
        for (std::size_t i = 0; i < cells.size() && numeric; ++i)
            numeric = parse_number(unquoted(cells[i]), row[i]);

        if (!numeric && columns == 0 && !have_header) {
            // The first line that is not all numbers names the columns.
            std::vector<std::string> names;
            for (auto c : cells) names.push_back(normalised_column_name(c));
            ix = column_named(names, {"x", "//x"});
            iy = column_named(names, {"y"});
            iz = column_named(names, {"z"});
            if (ix < 0 || iy < 0 || iz < 0)
                throw InputError(name, "line " + std::to_string(lines.line_number()) +
                                           ": the header names no x, y and z columns");
            inx = column_named(names, {"nx", "normal_x", "normalx", "n_x"});
            iny = column_named(names, {"ny", "normal_y", "normaly", "n_y"});
            inz = column_named(names, {"nz", "normal_z", "normalz", "n_z"});
            named_normals = inx >= 0 && iny >= 0 && inz >= 0;
            columns = cells.size();
            have_header = true;
            continue;
        }
        const std::string at = "line " + std::to_string(lines.line_number()) + ": ";
        if (columns == 0) {
            if (cells.size() < 3)
                throw InputError(
                    name, at + "expected at least 3 columns (x y z), found " + std::to_string(cells.size()));
            columns = cells.size();
        }
        if (cells.size() != columns)
            throw InputError(name, at + "expected " + std::to_string(columns) + " columns, found " +
                                       std::to_string(cells.size()));
        if (!numeric)
            for (std::size_t i = 0; i < cells.size(); ++i)
                if (!parse_number(unquoted(cells[i]), row[i]))
                    throw InputError(name, at + "column " + std::to_string(i + 1) + ": '" +
                                               std::string(cells[i].substr(0, 40)) + "' is not a number");
        g.vertices.emplace_back(row[ix], row[iy], row[iz]);
        if (named_normals)
            g.normals.emplace_back(row[inx], row[iny], row[inz]);
        else if (!have_header && columns >= 6)
            maybe_normals.emplace_back(row[3], row[4], row[5]);
    }
    // Without a header, columns 4-6 are normals only if every one is a unit vector; colours or intensities
    // are not.
    if (!maybe_normals.empty() &&
        std::all_of(maybe_normals.begin(), maybe_normals.end(),
                    [](const Eigen::Vector3d& n) { return std::abs(n.norm() - 1.0) < 0.01; }))
        g.normals = std::move(maybe_normals);
    return g;
}

RawGeometry parse_vtk(std::string_view bytes, const std::string& name) {
    LineReader lines(bytes);
    std::string_view line;
    if (!lines.next(line) || line.substr(0, 14) != "# vtk DataFile")
        throw InputError(name, "not a legacy VTK file (no '# vtk DataFile' first line)");
    std::string_view encoding;
    if (!lines.next(line) || !lines.next(encoding))
        throw InputError(name, "file is truncated (inside the header)");
    while (!encoding.empty() && (encoding.back() == ' ' || encoding.back() == '\t'))
        encoding.remove_suffix(1);
    if (encoding == "BINARY") throw InputError(name, "binary VTK is not supported; save it as ASCII");
    if (encoding != "ASCII") throw InputError(name, "line 3: expected ASCII or BINARY");

    TokenReader tokens(bytes.substr(std::min(lines.offset(), bytes.size())), lines.line_number() + 1);
    std::string_view t;
    while (tokens.next(t) && t != "POINTS") {
    }
    if (t != "POINTS") throw InputError(name, "has no POINTS section");
    double count = 0;
    // At most 10^12, as PLY's and PCD's counts: beyond size_t the cast is undefined (found by fuzz_vtk).
    if (!tokens.next(t) || !parse_number(t, count) || count < 0 || count > 1e12 ||
        count != std::floor(count) || !tokens.next(t))
        throw InputError(name, "line " + std::to_string(tokens.line()) + ": expected 'POINTS COUNT TYPE'");
    const std::size_t n = static_cast<std::size_t>(count);
    RawGeometry g;
    g.vertices.reserve(std::min(n, bytes.size() / 6));
    for (std::size_t i = 0; i < n; ++i) {
        double xyz[3];
        for (double& v : xyz) {
            if (!tokens.next(t))
                throw InputError(name, "file is truncated (expected " + std::to_string(n) +
                                           " points, found " + std::to_string(i) + ")");
            if (!parse_number(t, v))
                throw InputError(name, "line " + std::to_string(tokens.line()) + ": '" +
                                           std::string(t.substr(0, 40)) + "' is not a number");
        }
        g.vertices.emplace_back(xyz[0], xyz[1], xyz[2]);
    }
    // Numbers straight after the points mean the count is smaller than the data; a next section (a keyword)
    // is normal.
    if (tokens.next(t) && parse_number(t, count))
        g.warnings.push_back("numbers continue after the header's " + std::to_string(n) +
                             " points; the rest of the POINTS section was not read (a count smaller than the "
                             "data: is the file cut or half exported?)");
    return g;
}

}  // namespace partloc::io::detail
