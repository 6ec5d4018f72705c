#pragma once
// Work offsets for the controller (SPEC "Machining", issue 26 item 3): the placed workpiece frame
// T_machine_workpiece (machine frame, every axis at 0) written as the controller's own lines, one file per
// dialect in DIR/offsets/. Each writer is a pure function returning the file's text; write_work_offsets
// writes the files.
//
// Conventions, as the vendors document them (each p_machine = origin + R * p_workpiece):
// - Fanuc (Series 30i/300i descriptions B-63942EN/02, §5.44 "Tilted working plane command",
//   cncmanuals.com/fanuc/657/series-30i-300i-300is-model-a-descriptions/page/278): G10 L2 Pn X Y Z sets
//   workpiece offset n (G54..G59) in machine coordinates; G68.2 X Y Z I J K sets a feature coordinate
//   system at X Y Z of the workpiece coordinate system, I J K its Euler angles: about Z by I, then about the
//   new X by J, then about the new Z by K, so R = Rz(I) * Rx(J) * Rz(K).
// - Siemens Sinumerik (Function Manual K2 "Frames", 6FC5397-0BP10-2BA0 p. 56, easymanua.ls/siemens/
//   sinumerik-840-sl/manual?p=840; Programming Manual 6FC5398-2EP40-0BA0 p. 309): $P_UIFR[n] is settable
//   frame n (G54..G57 = 1..4, G505.. = 5..); CTRANS(X,x,Y,y,Z,z) : CROT(X,a,Y,b,Z,c) translates, then
//   rotates about the translated origin. With the default MD10600 $MN_FRAME_ANGLE_INPUT_MODE = 1 (RPY) the
//   rotations are "carried out in the order Z, Y', X''": R = Rz(c) * Ry(b) * Rx(a).
// - Heidenhain TNC (iTNC 530 user manual 340 422, p. 460, manualsdir.com/manuals/798663/
//   heidenhain-itnc-530-340-422.html?page=460; TNC 620 user manual 10/2017 p. 540; TNC7 81762x-17 "Preset
//   table"): the preset table row holds the preset's X Y Z (machine coordinates) and the 3D basic rotation
//   as spatial angles SPA SPB SPC, "rotations around the fixed machine coordinate system ... first around
//   the A axis, then B, and then C": R = Rz(SPC) * Ry(SPB) * Rx(SPA).
// - LinuxCNC (G-code reference, G10 L2; sourceforge.net/p/emc/mailman/message/26944307/): G10 L2 Pn X Y Z R
//   sets the origin of coordinate system n (G54..G59.3, P1..P9) "in terms of the not offset machine
//   coordinate system", and R "the rotation of the XY axis around the Z": R = Rz(R). No rotation about X or
//   Y can be given.
#include <Eigen/Geometry>
#include <filesystem>
#include <string>
#include <vector>

#include "partloc/pipeline/job.hpp"
#include "partloc/pipeline/result.hpp"

namespace partloc::io {

enum class OffsetDialect { Fanuc, Siemens, Heidenhain, LinuxCnc };

/// "fanuc", "siemens", "heidenhain", "linuxcnc" (the names job.yaml's output.offsets takes).
std::string dialect_name(OffsetDialect d);
/// The dialect of a name in output.offsets; false for an unknown name.
bool parse_dialect(const std::string& name, OffsetDialect& d);
/// The file in DIR/offsets/: fanuc.nc, siemens.mpf, heidenhain.h, linuxcnc.ngc.
std::string dialect_file(OffsetDialect d);
/// Every dialect's name, comma-separated, for the loader's messages.
std::string known_dialects();

/// The work offset numbers every dialect takes: 1..6 (G54..G59; Siemens G54..G57, G505, G506).
constexpr int kMaxWorkOffset = 6;

struct OffsetSettings {
    int work_offset = 1;  ///< 1 = G54 / the first preset
    bool inch = false;    ///< lengths in inches (G20, G70, INCH) instead of millimetres
    /// The corner of the part's bounding box (workpiece frame) farthest from the workpiece origin, in the
    /// file's units: where the error of what a dialect cannot represent is stated.
    Eigen::Vector3d far_corner = Eigen::Vector3d::Zero();
    std::vector<std::string> notes;  ///< further comment lines (the rotary axis that squares the part)
};

/// One dialect's file and what it leaves out.
struct WorkOffsetFile {
    OffsetDialect dialect = OffsetDialect::Fanuc;
    std::string file;  ///< name in DIR/offsets/
    std::string text;  ///< the file's text
    /// The frame as written (file units, the numbers as rounded in the file).
    Eigen::Isometry3d T_machine_workpiece_written = Eigen::Isometry3d::Identity();
    std::string cannot_represent;      ///< what the dialect cannot hold, empty when nothing
    double error_at_far_corner = 0.0;  ///< |T_written * c - T * c| at the far corner c (file units)
};

/// The file for `d` of the frame T_machine_workpiece (lengths in the file's units, as `settings.inch`).
WorkOffsetFile write_work_offset(OffsetDialect d, const Eigen::Isometry3d& T_machine_workpiece,
                                 const OffsetSettings& settings);

/// A rotary axis that carries the workpiece: the value that squares the part (brings its frame's
/// orientation nearest the nominal one) and the tilt that is then left.
struct RotaryAxisSquaring {
    std::string axis;
    double value_deg = 0.0;  ///< axis value that squares the part
    /// The rotation left at that value (machine frame), as a rotation vector in degrees: perpendicular to
    /// the axis, its components are the tilts about the machine axes.
    Eigen::Vector3d tilt_left_deg = Eigen::Vector3d::Zero();
    double tilt_left_angle_deg = 0.0;                                                ///< its angle
    Eigen::Isometry3d T_machine_workpiece_at_value = Eigen::Isometry3d::Identity();  ///< job units
};

/// For R_dev = R_located * R_nominal^T and a rotary axis of direction u: the value q minimising the angle
/// of Rot(u, q) * R_dev (the twist of R_dev about u, negated), and what is left.
RotaryAxisSquaring square_with_axis(const Axis& axis, const Eigen::Isometry3d& T_located,
                                    const Eigen::Isometry3d& T_nominal);

/// Everything the job's output.offsets asks for: the files' texts, or why there are none.
struct WorkOffsets {
    bool written = false;
    std::string reason;                                    ///< why no files, when not written
    std::string units = "mm";                              ///< of the files: mm or in
    Eigen::Vector3d far_corner = Eigen::Vector3d::Zero();  ///< workpiece frame, job units
    std::vector<WorkOffsetFile> files;
    std::vector<RotaryAxisSquaring> rotary;
};

/// The placed frame (today the located one: there is no placement yet) for each dialect in
/// job.output.offsets. No files when the workpiece was not located.
WorkOffsets work_offsets(const Job& job, const JobResult& result);

/// result.json's "offsets" object (JSON text), lengths in the job's units.
std::string work_offsets_json(const Job& job, const JobResult& result);

/// Writes DIR/offsets/<dialect file> for each dialect asked for (removing those of an earlier run when the
/// workpiece was not located). Returns the files written. Throws std::runtime_error naming a file that
/// cannot be written.
std::vector<std::filesystem::path> write_work_offsets(const std::filesystem::path& dir, const Job& job,
                                                      const JobResult& result);

}  // namespace partloc::io
