// STEP models (issue 27): real STEP files written by Open CASCADE itself in the test (a box, in millimetres
// and in metres; its faces named by editing the file's ADVANCED_FACE entities), read back through
// read_model and through a job.
#include <gtest/gtest.h>

#include <BRepPrimAPI_MakeBox.hxx>
#include <IFSelect_ReturnStatus.hxx>
#include <Interface_Static.hxx>
#include <Message.hxx>
#include <Message_Messenger.hxx>
#include <Message_PrinterOStream.hxx>
#include <STEPControl_Writer.hxx>
#include <filesystem>
#include <regex>
#include <string>

#include "partloc/io/cloud_io.hpp"
#include "partloc/io/job_io.hpp"
#include "partloc/pipeline/job.hpp"
#include "test_util.hpp"

namespace fs = std::filesystem;
using namespace partloc;

namespace {

/// A 10 x 20 x 30 mm box at (1, 2, 3) written as STEP with lengths in `unit` ("MM" or "M"); its six faces
/// named face_1 ... face_6 in the file's order when `named`.
void write_box(const fs::path& path, const char* unit, bool named) {
    Message::DefaultMessenger()->RemovePrinters(STANDARD_TYPE(Message_PrinterOStream));
    const TopoDS_Shape box = BRepPrimAPI_MakeBox(gp_Pnt(1, 2, 3), 10.0, 20.0, 30.0).Shape();
    Interface_Static::SetCVal("write.step.unit", unit);
    STEPControl_Writer writer;
    ASSERT_EQ(writer.Transfer(box, STEPControl_AsIs), IFSelect_RetDone);
    ASSERT_EQ(writer.Write(path.string().c_str()), IFSelect_RetDone);
    Interface_Static::SetCVal("write.step.unit", "MM");
    if (!named) return;
    std::string text = test::slurp(path), out;
    int k = 0;
    std::size_t at = 0;
    for (std::size_t hit; (hit = text.find("ADVANCED_FACE('", at)) != std::string::npos;) {
        const std::size_t name_start = hit + 15, name_end = text.find('\'', name_start);
        out += text.substr(at, name_start - at) + "face_" + std::to_string(++k);
        at = name_end;
    }
    out += text.substr(at);
    ASSERT_EQ(k, 6) << "expected six ADVANCED_FACE entities";
    test::spit(path, out);
}

double area(const open3d::geometry::TriangleMesh& m) { return m.GetSurfaceArea(); }

Eigen::Vector3d extent(const open3d::geometry::TriangleMesh& m) { return m.GetMaxBound() - m.GetMinBound(); }

}  // namespace

TEST(Step, ABoxReadsAsItsSixFacesInTheJobsUnits) {
    test::TempFolder tmp("partloc_step");
    write_box(tmp.dir / "box.step", "MM", false);
    const ModelSource mm = io::read_model(tmp.dir / "box.step", "box.step");
    ASSERT_TRUE(mm.mesh);
    EXPECT_NEAR(area(*mm.mesh), 2 * (10 * 20 + 10 * 30 + 20 * 30), 1e-6);
    EXPECT_TRUE(extent(*mm.mesh).isApprox(Eigen::Vector3d(10, 20, 30), 1e-9));
    EXPECT_TRUE(mm.mesh->GetMinBound().isApprox(Eigen::Vector3d(1, 2, 3), 1e-9));
    // Outward: the triangle normals of the face at z = 33 point up.
    int up = 0, total = 0;
    for (std::size_t t = 0; t < mm.mesh->triangles_.size(); ++t) {
        const auto& tri = mm.mesh->triangles_[t];
        bool top = true;
        for (int k = 0; k < 3; ++k) top = top && std::abs(mm.mesh->vertices_[tri[k]].z() - 33.0) < 1e-9;
        if (!top) continue;
        ++total;
        if (mm.mesh->triangle_normals_[t].z() > 0.99) ++up;
    }
    EXPECT_GT(total, 0);
    EXPECT_EQ(up, total);

    // The same box written in metres reads the same in millimetres, and in a job in inches as inches.
    write_box(tmp.dir / "box_m.stp", "M", false);
    const ModelSource m = io::read_model(tmp.dir / "box_m.stp", "box_m.stp");
    EXPECT_TRUE(extent(*m.mesh).isApprox(Eigen::Vector3d(10, 20, 30), 1e-6));
    io::ModelOptions inch;
    inch.step_scale = 1.0 / 25.4;
    const ModelSource in = io::read_model(tmp.dir / "box_m.stp", "box_m.stp", 1.0, nullptr, inch);
    EXPECT_TRUE(extent(*in.mesh).isApprox(Eigen::Vector3d(10, 20, 30) / 25.4, 1e-6));
}

TEST(Step, FacesAreChosenByTheirNamesInTheFile) {
    test::TempFolder tmp("partloc_step_faces");
    write_box(tmp.dir / "box.step", "MM", true);
    io::ModelOptions two;
    two.faces = {"face_1", "face_2"};
    const ModelSource picked = io::read_model(tmp.dir / "box.step", "box.step", 1.0, nullptr, two);
    ASSERT_TRUE(picked.mesh);
    // OCCT's box writes its faces in the order x-, x+, y-, y+, z-, z+: the two x faces, 20 x 30 each.
    EXPECT_NEAR(area(*picked.mesh), 2 * 20 * 30, 1e-6);
    EXPECT_NEAR(extent(*picked.mesh).x(), 10.0, 1e-9);

    io::ModelOptions missing;
    missing.faces = {"face_1", "lid"};
    try {
        (void)io::read_model(tmp.dir / "box.step", "box.step", 1.0, nullptr, missing);
        ADD_FAILURE() << "a face name the file does not have was accepted";
    } catch (const io::InputError& e) {
        const std::string what = e.what();
        EXPECT_NE(what.find("box.step"), std::string::npos) << what;
        EXPECT_NE(what.find("no face named 'lid'"), std::string::npos) << what;
        EXPECT_NE(what.find("face_6"), std::string::npos) << what;  // the names it has
    }
    // Faces by name from a file that cannot name them.
    test::spit(tmp.dir / "box.stl", "solid x\nendsolid x\n");
    EXPECT_THROW((void)io::read_model(tmp.dir / "box.stl", "box.stl", 1.0, nullptr, two), io::InputError);
}

TEST(Step, AFileWithoutALengthUnitOrNotSTEPIsRefusedByName) {
    test::TempFolder tmp("partloc_step_bad");
    write_box(tmp.dir / "box.step", "MM", false);
    // The length unit taken out of the file's units context (its first unit).
    std::string text = test::slurp(tmp.dir / "box.step");
    const std::string no_unit = std::regex_replace(
        text, std::regex("GLOBAL_UNIT_ASSIGNED_CONTEXT\\s*\\(\\(#[0-9]+,"), "GLOBAL_UNIT_ASSIGNED_CONTEXT((");
    ASSERT_NE(no_unit, text);
    test::spit(tmp.dir / "nounit.step", no_unit);
    try {
        (void)io::read_model(tmp.dir / "nounit.step", "nounit.step");
        ADD_FAILURE() << "a STEP file without a length unit was read";
    } catch (const io::InputError& e) {
        EXPECT_NE(std::string(e.what()).find("nounit.step"), std::string::npos) << e.what();
    }
    test::spit(tmp.dir / "junk.stp", "this is not STEP\n");
    EXPECT_THROW((void)io::read_model(tmp.dir / "junk.stp", "junk.stp"), io::InputError);
    EXPECT_THROW((void)io::read_model(tmp.dir / "absent.step", "absent.step"), io::InputError);
}

TEST(Step, AJobTakesSTEPModelsWithFacesAndRefusesUnitsForThem) {
    test::TempFolder tmp("partloc_step_job");
    write_box(tmp.dir / "part.step", "M", true);
    test::spit(tmp.dir / "scan.xyz", "0 0 0\n1 0 0\n0 1 0\n0 0 1\n1 1 1\n");
    const std::string head =
        "units: mm\nfiducials:\n  - {name: A, model: part.step, pose: {origin: [0, 0, 0], euler_xyz_deg: [0, "
        "0, 0]}}\n"
        "scans:\n  - scan.xyz\n";
    test::spit(tmp.dir / "job.yaml",
               head +
                   "workpiece:\n  reference_surfaces: {file: part.step, faces: [face_5, face_6]}\n"
                   "  final_part: part.step\n");
    const Job job = io::load_job(tmp.dir / "job.yaml");
    ASSERT_TRUE(job.workpiece.reference_surfaces.mesh);
    EXPECT_NEAR(job.workpiece.reference_surfaces.mesh->GetSurfaceArea(), 2 * 10 * 20, 1e-6);
    ASSERT_TRUE(job.workpiece.final_part && job.workpiece.final_part->mesh);
    EXPECT_NEAR(job.workpiece.final_part->mesh->GetSurfaceArea(), 2200, 1e-6);

    test::spit(tmp.dir / "units.yaml",
               head + "workpiece:\n  reference_surfaces: {file: part.step, units: in}\n");
    test::expect_job_error(tmp.dir / "units.yaml", "a STEP file says its own units");
    test::spit(tmp.dir / "stl.yaml",
               head + "workpiece:\n  reference_surfaces: {file: scan.xyz, faces: [top]}\n");
    test::expect_job_error(tmp.dir / "stl.yaml", "faces can be chosen by name in STEP files only");
    test::spit(tmp.dir / "lid.yaml",
               head + "workpiece:\n  reference_surfaces: {file: part.step, faces: [lid]}\n");
    try {
        (void)io::load_job(tmp.dir / "lid.yaml");
        ADD_FAILURE() << "a face name the file does not have was accepted";
    } catch (const io::InputError& e) {
        EXPECT_NE(std::string(e.what()).find("part.step"), std::string::npos) << e.what();
        EXPECT_NE(std::string(e.what()).find("no face named 'lid'"), std::string::npos) << e.what();
    }
}
