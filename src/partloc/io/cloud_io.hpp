#pragma once
// Readers and writers of point clouds and meshes. The format is chosen by the file's extension
// (case-insensitive):
//   points: .ply (ascii, binary little/big endian; extra elements and properties are skipped), .pcd (ascii,
//           binary, binary_compressed), .xyz .txt .csv (columns separated by spaces, tabs, commas or
//           semicolons, with or without a header line naming the columns), .vtk (legacy ASCII, its POINTS)
//   meshes: .stl (ascii, binary), .ply with a face element, .obj (polygons are split into triangles),
//           .step .stp (Open CASCADE, triangulated; in millimetres, read_model converts to the job's units)
// Every reader either returns the whole file or throws InputError naming the file and the problem: a
// missing, unreadable, truncated, malformed, empty or NaN-only file never yields a partial result. The
// readers never print (Open3D's own console output is silenced while they run).
#include <open3d/geometry/PointCloud.h>
#include <open3d/geometry/TriangleMesh.h>

#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include "partloc/io/input_error.hpp"
#include "partloc/pipeline/job.hpp"

namespace partloc::io {

/// Reads the points of a cloud file (a mesh file gives its vertices). Points with a non-finite coordinate
/// are dropped; normals are kept when the file has them (all finite). Coordinates are multiplied by
/// `units_scale` (file units -> job units, > 0). `display_name` names the file in error messages (the path
/// as the user wrote it). Throws InputError when the file is missing, unreadable, truncated or malformed, or
/// holds no finite point.
/// `warnings`, when given, receives what a person should know though the file was read (data beyond the
/// header's count), each a sentence naming the file.
std::shared_ptr<open3d::geometry::PointCloud> read_point_cloud(const std::filesystem::path& path,
                                                               const std::string& display_name,
                                                               double units_scale = 1.0,
                                                               std::vector<std::string>* warnings = nullptr);

/// Reads a triangle mesh (STL, PLY with faces, OBJ). Vertices are multiplied by `units_scale`; STL's
/// repeated corners are merged into shared vertices; triangle and vertex normals are computed when the file
/// has none. Throws InputError as read_point_cloud does, and when the file has no faces or a face refers to
/// a vertex that does not exist.
std::shared_ptr<open3d::geometry::TriangleMesh> read_mesh(const std::filesystem::path& path,
                                                          const std::string& display_name,
                                                          double units_scale = 1.0);

/// What reading a model takes beyond its units: STEP's (.step, .stp), whose coordinates come in the unit the
/// file declares, read as millimetres.
struct ModelOptions {
    double step_scale = 1.0;         ///< STEP: job units per millimetre (units_scale does not apply)
    std::vector<std::string> faces;  ///< STEP: only the faces the file names so; empty: every face
    double deflection = 0.0;         ///< STEP: the triangulation's chord tolerance, job units; 0: 0.02 mm
};

/// Reads a model as the job uses it (pipeline/job.hpp): a mesh when the file has faces (STL and STEP always;
/// PLY and OBJ when they have faces), its points otherwise. ModelSource::file is `display_name`. Faces by
/// name for any other format than STEP are refused.
ModelSource read_model(const std::filesystem::path& path, const std::string& display_name,
                       double units_scale = 1.0, std::vector<std::string>* warnings = nullptr,
                       const ModelOptions& options = {});

/// True for the extensions read as STEP.
bool is_step_file(const std::filesystem::path& path);

/// Writes `cloud` as binary little-endian PLY (float x y z, and nx ny nz / red green blue when the cloud
/// has them), atomically. `comment` goes into the header (e.g. "units mm"). Throws std::runtime_error
/// naming `path` when it cannot be written.
void write_point_cloud(const std::filesystem::path& path, const open3d::geometry::PointCloud& cloud,
                       const std::string& comment = "");

/// Writes `mesh` as binary STL, atomically. Facet normals are the mesh's triangle normals when it has them,
/// else computed from the corners (zero for a degenerate triangle). `comment` goes into the 80-byte header.
/// Throws std::runtime_error naming `path` when it cannot be written.
void write_mesh(const std::filesystem::path& path, const open3d::geometry::TriangleMesh& mesh,
                const std::string& comment = "");

}  // namespace partloc::io
