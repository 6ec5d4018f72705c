#pragma once
// Internal to the I/O layer: one parser per file format, each returning the file's geometry whole or
// throwing InputError(name, problem). The public entry points are in cloud_io.hpp.
#include <Eigen/Core>
#include <cstddef>
#include <filesystem>
#include <string>
#include <string_view>
#include <vector>

#include "partloc/io/input_error.hpp"

namespace partloc::io::detail {

/// What a file holds, in its own units. Points with non-finite coordinates are still in; the caller drops
/// them (clouds) or rejects them (meshes).
struct RawGeometry {
    std::vector<Eigen::Vector3d> vertices;
    std::vector<Eigen::Vector3d> normals;    ///< empty, or one per vertex
    std::vector<Eigen::Vector3i> triangles;  ///< indices into vertices, checked in range
    /// What a person should know though the file was read: data beyond the header's counts (a count
    /// smaller than the data is how a half-exported file looks), far points dropped. Sentences without the
    /// file's name.
    std::vector<std::string> warnings;
};

/// The whole file as bytes. Throws InputError for a missing file, a folder, an unreadable file.
std::string read_file_bytes(const std::filesystem::path& path, const std::string& name);

RawGeometry parse_ply(std::string_view bytes, const std::string& name);
RawGeometry parse_stl(std::string_view bytes, const std::string& name);
RawGeometry parse_obj(std::string_view bytes, const std::string& name);
/// .xyz .txt .csv: one point per line, columns x y z [nx ny nz ...], optional header line naming them.
RawGeometry parse_columns(std::string_view bytes, const std::string& name);
/// Legacy VTK, ASCII: the POINTS section.
RawGeometry parse_vtk(std::string_view bytes, const std::string& name);
/// How a STEP file is read: which faces, and the triangulation's tolerances.
struct StepOptions {
    std::vector<std::string> faces;  ///< only the faces the file names so; empty: every face
    double deflection_mm = 0.02;     ///< chord tolerance of the triangulation (mm)
    double angle_rad = 0.2;          ///< angular tolerance of the triangulation
};
/// STEP (io/step_format.cpp): the shapes' faces triangulated, in millimetres whatever unit the file
/// declares; a file that declares none, has no shape, or lacks a face asked for by name is refused.
RawGeometry read_step(const std::filesystem::path& path, const std::string& name, const StepOptions& options);

/// PCD: ascii parsed here; binary and binary_compressed checked here against the header, decoded by Open3D.
RawGeometry read_pcd(const std::filesystem::path& path, std::string_view bytes, const std::string& name);

// Text helpers shared by the parsers.

/// Parses a whole token as a number: decimal or exponent notation, optional sign, nan, inf. False otherwise.
bool parse_number(std::string_view token, double& value);

/// True when the bytes hold a NUL in their first few kilobytes: a binary file given where text is expected.
bool looks_binary(std::string_view bytes);

/// Splits a line into tokens at spaces, tabs, commas and semicolons (empty fields between commas count).
std::vector<std::string_view> split_columns(std::string_view line);

/// Walks text line by line, counting lines from 1 and stripping a trailing '\r'.
class LineReader {
  public:
    explicit LineReader(std::string_view text) : text_(text) {}
    bool next(std::string_view& line);
    std::size_t line_number() const { return line_number_; }
    std::size_t offset() const { return pos_; }

  private:
    std::string_view text_;
    std::size_t pos_ = 0;
    std::size_t line_number_ = 0;
};

/// Walks text token by token (whitespace separated), tracking the line of the last token.
class TokenReader {
  public:
    explicit TokenReader(std::string_view text, std::size_t first_line = 1)
        : text_(text), line_(first_line) {}
    /// False at the end of the text.
    bool next(std::string_view& token);
    std::size_t line() const { return line_; }

  private:
    std::string_view text_;
    std::size_t pos_ = 0;
    std::size_t line_;
};

/// "vertices" for "vertex", "faces" for "face", "points" for "point", "'x' elements" otherwise.
std::string plural_of(const std::string& element);

}  // namespace partloc::io::detail
