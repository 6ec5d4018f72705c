#include "partloc/io/cloud_io.hpp"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <fstream>
#include <stdexcept>

#include "partloc/io/atomic_file.hpp"
#include "partloc/io/formats.hpp"

namespace partloc::io {

namespace fs = std::filesystem;
using detail::RawGeometry;

namespace {

enum class Format { Ply, Pcd, Columns, Vtk, Stl, Obj, Step };

/// The file name's extension in lower case (".ply").
std::string extension_of(const fs::path& path) {
    std::string ext = path.extension().string();
    std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return std::tolower(c); });
    return ext;
}

bool is_step_extension(const std::string& ext) { return ext == ".step" || ext == ".stp"; }

Format format_of(const fs::path& path, const std::string& name) {
    const std::string ext = extension_of(path);
    if (ext == ".ply") return Format::Ply;
    if (ext == ".pcd") return Format::Pcd;
    if (ext == ".xyz" || ext == ".txt" || ext == ".csv" || ext == ".asc") return Format::Columns;
    if (ext == ".vtk") return Format::Vtk;
    if (ext == ".stl") return Format::Stl;
    if (ext == ".obj") return Format::Obj;
    if (is_step_extension(ext)) return Format::Step;
    throw InputError(
        name, (ext.empty() ? std::string("file name has no extension") : "unknown file type '" + ext + "'") +
                  " (known: .ply .pcd .xyz .txt .csv .asc .vtk .stl .obj .step .stp)");
}

RawGeometry read_raw(const fs::path& path, const std::string& name,
                     const detail::StepOptions& step = detail::StepOptions{}) {
    const Format format = format_of(path, name);
    if (format == Format::Step) return detail::read_step(path, name, step);
    const std::string bytes = detail::read_file_bytes(path, name);
    switch (format) {
        case Format::Step:
            break;
        case Format::Ply:
            return detail::parse_ply(bytes, name);
        case Format::Pcd:
            return detail::read_pcd(path, bytes, name);
        case Format::Columns:
            return detail::parse_columns(bytes, name);
        case Format::Vtk:
            return detail::parse_vtk(bytes, name);
        case Format::Stl:
            return detail::parse_stl(bytes, name);
        case Format::Obj:
            return detail::parse_obj(bytes, name);
    }
    throw InputError(name, "unknown file type");
}

void check_scale(double units_scale, const std::string& name) {
    if (!std::isfinite(units_scale) || units_scale <= 0)
        throw std::invalid_argument(name + ": units scale must be a positive number, got " +
                                    std::to_string(units_scale));
}

std::shared_ptr<open3d::geometry::PointCloud> to_cloud(RawGeometry&& g, const std::string& name,
                                                       double scale) {
    if (g.vertices.empty()) throw InputError(name, "file has no points");
    auto cloud = std::make_shared<open3d::geometry::PointCloud>();
    const bool with_normals = g.normals.size() == g.vertices.size();
    // Every point finite and no normals (a scan's usual form): the parser's points become the cloud's, scaled
    // in place, instead of copied one by one.
    if (!with_normals && std::all_of(g.vertices.begin(), g.vertices.end(),
                                     [](const Eigen::Vector3d& v) { return v.allFinite(); })) {
        cloud->points_ = std::move(g.vertices);
        if (scale != 1.0)
            for (auto& p : cloud->points_) p *= scale;
        return cloud;
    }
    cloud->points_.reserve(g.vertices.size());
    if (with_normals) cloud->normals_.reserve(g.vertices.size());
    bool normals_finite = true;
    for (std::size_t i = 0; i < g.vertices.size(); ++i) {
        if (!g.vertices[i].allFinite()) continue;
        cloud->points_.push_back(g.vertices[i] * scale);
        if (with_normals) {
            normals_finite = normals_finite && g.normals[i].allFinite();
            cloud->normals_.push_back(g.normals[i]);
        }
    }
    if (cloud->points_.empty())
        throw InputError(name, "file has no finite points (all " + std::to_string(g.vertices.size()) +
                                   " are NaN or infinite)");
    // A normal that is not finite is no normal; rather none than some (the pipeline estimates them).
    if (!normals_finite) cloud->normals_.clear();
    return cloud;
}

std::shared_ptr<open3d::geometry::TriangleMesh> to_mesh(RawGeometry&& g, const std::string& name,
                                                        double scale) {
    if (g.triangles.empty())
        throw InputError(name, g.vertices.empty() ? "file has no vertices and no faces"
                                                  : "file has no faces (it is a point cloud, not a mesh)");
    for (std::size_t i = 0; i < g.vertices.size(); ++i)
        if (!g.vertices[i].allFinite())
            throw InputError(name,
                             "vertex " + std::to_string(i) + " has a coordinate that is NaN or infinite");
    auto mesh = std::make_shared<open3d::geometry::TriangleMesh>();
    mesh->vertices_ = std::move(g.vertices);
    for (auto& v : mesh->vertices_) v *= scale;
    mesh->triangles_ = std::move(g.triangles);
    mesh->ComputeTriangleNormals(true);
    const bool normals_usable = g.normals.size() == mesh->vertices_.size() &&
                                std::all_of(g.normals.begin(), g.normals.end(), [](const Eigen::Vector3d& n) {
                                    return n.allFinite() && n.norm() > 0;
                                });
    if (normals_usable) {
        mesh->vertex_normals_ = std::move(g.normals);
        for (auto& n : mesh->vertex_normals_) n.normalize();
    } else {
        mesh->ComputeVertexNormals(true);
    }
    return mesh;
}

void put_u32(std::string& out, std::uint32_t v) {
    for (int i = 0; i < 4; ++i) out.push_back(static_cast<char>((v >> (8 * i)) & 0xff));
}

void put_f32(std::string& out, double value) {
    const float f = static_cast<float>(value);
    std::uint32_t u;
    std::memcpy(&u, &f, 4);
    put_u32(out, u);
}

std::string printable(const std::string& s) {
    std::string out;
    for (char c : s) out += std::isprint(static_cast<unsigned char>(c)) ? c : ' ';
    return out;
}

void write_bytes_atomically(const fs::path& path, const std::string& bytes) {
    write_atomically(path, [&](const fs::path& tmp) {
        std::ofstream out(tmp, std::ios::binary);
        out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
        out.close();
        return static_cast<bool>(out);
    });
}

}  // namespace

static void pass_warnings(const RawGeometry& g, const std::string& name, std::vector<std::string>* warnings) {
    if (warnings)
        for (const auto& w : g.warnings) warnings->push_back(name + ": " + w);
}

std::shared_ptr<open3d::geometry::PointCloud> read_point_cloud(const fs::path& path,
                                                               const std::string& display_name,
                                                               double units_scale,
                                                               std::vector<std::string>* warnings) {
    check_scale(units_scale, display_name);
    RawGeometry g = read_raw(path, display_name);
    pass_warnings(g, display_name, warnings);
    return to_cloud(std::move(g), display_name, units_scale);
}

std::shared_ptr<open3d::geometry::TriangleMesh> read_mesh(const fs::path& path,
                                                          const std::string& display_name,
                                                          double units_scale) {
    check_scale(units_scale, display_name);
    return to_mesh(read_raw(path, display_name), display_name, units_scale);
}

bool is_step_file(const fs::path& path) { return is_step_extension(extension_of(path)); }

ModelSource read_model(const fs::path& path, const std::string& display_name, double units_scale,
                       std::vector<std::string>* warnings, const ModelOptions& options) {
    check_scale(units_scale, display_name);
    const Format format = format_of(path, display_name);
    if (!options.faces.empty() && format != Format::Step)
        throw InputError(display_name, "faces can be chosen by name in STEP files only");
    detail::StepOptions step;
    step.faces = options.faces;
    if (format == Format::Step) {
        check_scale(options.step_scale, display_name);
        units_scale = options.step_scale;
        if (options.deflection > 0) step.deflection_mm = options.deflection / options.step_scale;
    }
    RawGeometry g = read_raw(path, display_name, step);
    pass_warnings(g, display_name, warnings);
    ModelSource model;
    model.file = display_name;
    // STL has no way to hold points alone, so an STL without facets is an error, not an empty cloud.
    if (!g.triangles.empty() || format == Format::Stl || format == Format::Step)
        model.mesh = to_mesh(std::move(g), display_name, units_scale);
    else
        model.points = to_cloud(std::move(g), display_name, units_scale);
    return model;
}

void write_point_cloud(const fs::path& path, const open3d::geometry::PointCloud& cloud,
                       const std::string& comment) {
    const std::size_t n = cloud.points_.size();
    const bool normals = cloud.normals_.size() == n && n > 0;
    const bool colors = cloud.colors_.size() == n && n > 0;
    std::string out = "ply\nformat binary_little_endian 1.0\n";
    if (!comment.empty()) out += "comment " + printable(comment) + "\n";
    out += "element vertex " + std::to_string(n) + "\nproperty float x\nproperty float y\nproperty float z\n";
    if (normals) out += "property float nx\nproperty float ny\nproperty float nz\n";
    if (colors) out += "property uchar red\nproperty uchar green\nproperty uchar blue\n";
    out += "end_header\n";
    out.reserve(out.size() + n * (12 + (normals ? 12 : 0) + (colors ? 3 : 0)));
    for (std::size_t i = 0; i < n; ++i) {
        for (int k = 0; k < 3; ++k) put_f32(out, cloud.points_[i][k]);
        if (normals)
            for (int k = 0; k < 3; ++k) put_f32(out, cloud.normals_[i][k]);
        if (colors)
            for (int k = 0; k < 3; ++k)
                out.push_back(
                    static_cast<char>(std::lround(std::clamp(cloud.colors_[i][k], 0.0, 1.0) * 255.0)));
    }
    write_bytes_atomically(path, out);
}

void write_mesh(const fs::path& path, const open3d::geometry::TriangleMesh& mesh,
                const std::string& comment) {
    // The 80-byte header must not start with "solid", or readers take the file for ascii STL.
    std::string header =
        printable("binary STL" + (comment.empty() ? std::string() : " " + comment)).substr(0, 80);
    header.resize(80, ' ');
    std::string out = header;
    const std::size_t n = mesh.triangles_.size();
    put_u32(out, static_cast<std::uint32_t>(n));
    out.reserve(out.size() + 50 * n);
    const bool given_normals = mesh.triangle_normals_.size() == n;
    for (std::size_t t = 0; t < n; ++t) {
        const Eigen::Vector3i& tri = mesh.triangles_[t];
        const Eigen::Vector3d a = mesh.vertices_.at(tri[0]), b = mesh.vertices_.at(tri[1]),
                              c = mesh.vertices_.at(tri[2]);
        Eigen::Vector3d normal = given_normals ? mesh.triangle_normals_[t] : (b - a).cross(c - a);
        normal = normal.norm() > 0 && normal.allFinite() ? normal.normalized() : Eigen::Vector3d::Zero();
        for (const Eigen::Vector3d& v : {normal, a, b, c})
            for (int k = 0; k < 3; ++k) put_f32(out, v[k]);
        out.push_back(0);  // attribute byte count
        out.push_back(0);
    }
    write_bytes_atomically(path, out);
}

}  // namespace partloc::io
