// STEP models (.step, .stp; issue 27): read by Open CASCADE's STEP translator from Debian's packages,
// triangulated by its BRepMesh_IncrementalMesh. Only here does the project link Open CASCADE.
#include <BRepMesh_IncrementalMesh.hxx>
#include <BRep_Tool.hxx>
#include <IFSelect_ReturnStatus.hxx>
#include <Interface_InterfaceModel.hxx>
#include <Interface_Static.hxx>
#include <Message.hxx>
#include <Message_Messenger.hxx>
#include <Message_PrinterOStream.hxx>
#include <Poly_Triangulation.hxx>
#include <STEPControl_Reader.hxx>
#include <StepShape_Face.hxx>
#include <TColStd_SequenceOfAsciiString.hxx>
#include <TCollection_HAsciiString.hxx>
#include <TopExp_Explorer.hxx>
#include <TopLoc_Location.hxx>
#include <TopoDS.hxx>
#include <TopoDS_Face.hxx>
#include <TransferBRep.hxx>
#include <Transfer_TransientProcess.hxx>
#include <XSControl_TransferReader.hxx>
#include <XSControl_WorkSession.hxx>
#include <algorithm>
#include <map>
#include <mutex>
#include <set>

#include "partloc/io/formats.hpp"

namespace partloc::io::detail {

namespace {

/// Open CASCADE's translator keeps its parameters (Interface_Static) and its messenger process-wide: one
/// file at a time.
std::mutex& step_mutex() {
    static std::mutex m;
    return m;
}

/// The translator reports to stdout; the readers never print (cloud_io.hpp).
void silence_open_cascade() {
    static std::once_flag once;
    std::call_once(once, [] {
        const Handle(Message_Messenger)& messenger = Message::DefaultMessenger();
        messenger->RemovePrinters(STANDARD_TYPE(Message_PrinterOStream));
    });
}

/// Appends face `f`'s triangulation (made by BRepMesh) to `g`, its triangles turned outward.
void append_face(const TopoDS_Face& f, RawGeometry& g) {
    TopLoc_Location loc;
    const Handle(Poly_Triangulation) tri = BRep_Tool::Triangulation(f, loc);
    if (tri.IsNull()) return;
    const gp_Trsf T = loc.Transformation();
    const int base = static_cast<int>(g.vertices.size());
    for (Standard_Integer i = 1; i <= tri->NbNodes(); ++i) {
        const gp_Pnt p = tri->Node(i).Transformed(T);
        g.vertices.emplace_back(p.X(), p.Y(), p.Z());
    }
    const bool reversed = f.Orientation() == TopAbs_REVERSED;
    for (Standard_Integer i = 1; i <= tri->NbTriangles(); ++i) {
        Standard_Integer a = 0, b = 0, c = 0;
        tri->Triangle(i).Get(a, b, c);
        if (reversed) std::swap(b, c);
        g.triangles.emplace_back(base + a - 1, base + b - 1, base + c - 1);
    }
}

}  // namespace

RawGeometry read_step(const std::filesystem::path& path, const std::string& name,
                      const StepOptions& options) {
    // The file's existence and kind checked as for every format (a folder, a device, a missing file).
    (void)read_file_bytes(path, name);
    const std::lock_guard<std::mutex> lock(step_mutex());
    silence_open_cascade();
    STEPControl_Reader reader;
    if (reader.ReadFile(path.string().c_str()) != IFSelect_RetDone)
        throw InputError(name, "not a STEP file Open CASCADE can read");
    TColStd_SequenceOfAsciiString lengths, angles, solid_angles;
    reader.FileUnits(lengths, angles, solid_angles);
    // A units context without a length unit comes back as one empty name.
    bool declared = false;
    for (Standard_Integer i = 1; i <= lengths.Length(); ++i) declared = declared || !lengths(i).IsEmpty();
    if (!declared)
        throw InputError(name, "the STEP file declares no length unit: its coordinates could be in any unit");
    // Coordinates in millimetres whatever the file's unit (the translator converts them).
    Interface_Static::SetCVal("xstep.cascade.unit", "MM");
    reader.TransferRoots();
    const TopoDS_Shape shape = reader.OneShape();
    if (shape.IsNull()) throw InputError(name, "the STEP file holds no shape");

    std::vector<TopoDS_Face> faces;
    if (options.faces.empty()) {
        for (TopExp_Explorer e(shape, TopAbs_FACE); e.More(); e.Next())
            faces.push_back(TopoDS::Face(e.Current()));
    } else {
        // Faces by the names the file gives them (the name of each ADVANCED_FACE or FACE_SURFACE entity).
        const std::set<std::string> wanted(options.faces.begin(), options.faces.end());
        std::set<std::string> found, all_names;
        const Handle(XSControl_WorkSession) ws = reader.WS();
        const Handle(Interface_InterfaceModel) model = ws->Model();
        const Handle(Transfer_TransientProcess) tp = ws->TransferReader()->TransientProcess();
        for (Standard_Integer i = 1; i <= model->NbEntities(); ++i) {
            const Handle(StepShape_Face) f = Handle(StepShape_Face)::DownCast(model->Value(i));
            if (f.IsNull() || f->Name().IsNull()) continue;
            const std::string face_name = f->Name()->ToCString();
            if (face_name.empty()) continue;
            all_names.insert(face_name);
            if (!wanted.count(face_name)) continue;
            const TopoDS_Shape s = TransferBRep::ShapeResult(tp, model->Value(i));
            if (s.IsNull() || s.ShapeType() != TopAbs_FACE) continue;
            faces.push_back(TopoDS::Face(s));
            found.insert(face_name);
        }
        for (const std::string& w : options.faces)
            if (!found.count(w)) {
                std::string known;
                for (const std::string& n : all_names) {
                    if (known.size() > 200) {
                        known += ", ...";
                        break;
                    }
                    known += (known.empty() ? "" : ", ") + n;
                }
                throw InputError(name, "no face named '" + w + "' in the STEP file (" +
                                           (known.empty() ? std::string("it names no faces")
                                                          : "its faces are named " + known) +
                                           ")");
            }
    }
    BRepMesh_IncrementalMesh mesher(shape, options.deflection_mm, Standard_False, options.angle_rad,
                                    Standard_True);
    RawGeometry g;
    for (const TopoDS_Face& f : faces) append_face(f, g);
    if (g.triangles.empty()) throw InputError(name, "the STEP file's shape has no faces to triangulate");
    return g;
}

}  // namespace partloc::io::detail
