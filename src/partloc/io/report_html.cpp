#include "partloc/io/report_html.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <numeric>
#include <sstream>

#include "partloc/core/geometry.hpp"
#include "partloc/core/localize.hpp"
#include "partloc/io/report_view3d.hpp"

namespace partloc::io {

namespace {

std::string fixed(double v, int decimals) {
    if (!std::isfinite(v)) return "–";
    char buffer[64];
    std::snprintf(buffer, sizeof buffer, "%.*f", decimals, v);
    std::string s = buffer;
    if (s.find_first_not_of("-0.") == std::string::npos)
        s = buffer[0] == '-' ? s.substr(1) : s;  // no "-0.000"
    return s;
}

double millimetres_per_unit_or_one(const std::string& units) {
    try {
        return millimetres_per_unit(units);
    } catch (const std::invalid_argument&) {
        return 1.0;  // the job loader rejects unknown units; a hand-made Job may still have one
    }
}

/// Decimals that show lengths to about a micrometre: 3 in mm, 6 in m, 4 in inches.
int length_decimals(const std::string& units) {
    const double mm = millimetres_per_unit_or_one(units);
    return std::clamp(static_cast<int>(std::lround(3.0 + std::log10(mm))), 0, 9);
}

struct Formatter {
    int length_decimals = 3;
    std::string units;
    std::string length(double v) const { return fixed(v, length_decimals); }
    std::string angle(double v) const { return fixed(v, 3); }
    std::string vec(const Eigen::Vector3d& v, bool angles = false) const {
        return (angles ? angle(v.x()) : length(v.x())) + ", " + (angles ? angle(v.y()) : length(v.y())) +
               ", " + (angles ? angle(v.z()) : length(v.z()));
    }
};

std::string axis_values(const AxisValues& q) {
    std::string s;
    for (const auto& [name, value] : q)
        s += (s.empty() ? "" : ", ") + std::string("axis ") + escape_html(name) + " = " + fixed(value, 3);
    return s.empty() ? "axes at 0" : s;
}

std::string chain(const std::vector<std::string>& axes) {
    std::string s;
    for (const auto& a : axes) s += (s.empty() ? "" : " → ") + std::string("axis ") + escape_html(a);
    return s.empty() ? "fixed" : s;
}

std::string model_summary(const ModelSource& m) {
    if (m.mesh)
        return escape_html(m.file) + " <span class=dim>(mesh, " + std::to_string(m.mesh->triangles_.size()) +
               " triangles)</span>";
    if (m.points)
        return escape_html(m.file) + " <span class=dim>(" + std::to_string(m.points->points_.size()) +
               " points)</span>";
    return escape_html(m.file);
}

std::string pose_cells(const Eigen::Isometry3d& T, const Formatter& f) {
    const Eigen::Vector3d e = euler_xyz_deg(T.linear());
    std::string s;
    for (int i = 0; i < 3; ++i) s += "<td class=num>" + f.length(T.translation()[i]) + "</td>";
    for (int i = 0; i < 3; ++i) s += "<td class=num>" + f.angle(e[i]) + "</td>";
    return s;
}

/// One orthographic view: which machine axes run right and up, and which one points at the viewer.
struct View {
    const char* title;
    int right, up, toward;
    double toward_sign;  ///< +1 when larger `toward` coordinates are nearer the viewer
};

/// A round length (1, 2 or 5 times a power of ten) near `target`.
double round_length(double target) {
    const double p = std::pow(10.0, std::floor(std::log10(target)));
    for (double m : {5.0, 2.0, 1.0})
        if (m * p <= target) return m * p;
    return p;
}

std::string svg_view(const View& v, const std::vector<Eigen::Vector3d>& points,
                     const std::vector<std::pair<Eigen::Isometry3d, bool>>& frames, double axis_length,
                     const Formatter& f) {
    constexpr double W = 360, H = 300, margin = 18;
    Eigen::Vector2d lo(1e300, 1e300), hi(-1e300, -1e300);
    const auto grow = [&](const Eigen::Vector3d& p) {
        const Eigen::Vector2d q(p[v.right], p[v.up]);
        lo = lo.cwiseMin(q);
        hi = hi.cwiseMax(q);
    };
    for (const auto& p : points) grow(p);
    for (const auto& [T, located] : frames) {
        grow(T.translation());
        for (int a = 0; a < 3; ++a) grow(T * (axis_length * Eigen::Vector3d::Unit(a)));
    }
    Eigen::Vector2d extent = (hi - lo).cwiseMax(1e-12);
    const double scale = std::min((W - 2 * margin) / extent.x(), (H - 2 * margin - 14) / extent.y());
    const Eigen::Vector2d centre = (lo + hi) / 2;
    const auto to_svg = [&](const Eigen::Vector3d& p) {
        return Eigen::Vector2d(W / 2 + (p[v.right] - centre.x()) * scale,
                               (H - 14) / 2 - (p[v.up] - centre.y()) * scale);
    };

    std::ostringstream s;
    s << "<figure><svg xmlns='http://www.w3.org/2000/svg' width='" << W << "' height='" << H
      << "' viewBox='0 0 " << W << " " << H
      << "'><rect width='100%' height='100%' fill='#fafafa' stroke='#ccc'/>";

    // Far points first, so the near ones are drawn over them; nearer is darker.
    std::vector<std::size_t> order(points.size());
    std::iota(order.begin(), order.end(), 0);
    std::sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) {
        return v.toward_sign * points[a][v.toward] < v.toward_sign * points[b][v.toward];
    });
    double dmin = 1e300, dmax = -1e300;
    for (const auto& p : points) {
        dmin = std::min(dmin, v.toward_sign * p[v.toward]);
        dmax = std::max(dmax, v.toward_sign * p[v.toward]);
    }
    s << "<g stroke='none'>";
    for (std::size_t i : order) {
        const Eigen::Vector2d q = to_svg(points[i]);
        const double t = dmax > dmin ? (v.toward_sign * points[i][v.toward] - dmin) / (dmax - dmin) : 1.0;
        const int grey = static_cast<int>(std::lround(200 - 150 * t));
        s << "<circle cx='" << fixed(q.x(), 1) << "' cy='" << fixed(q.y(), 1) << "' r='1.1' fill='rgb("
          << grey << "," << grey << "," << grey + 20 << ")'/>";
    }
    s << "</g>";

    static const char* colours[3] = {"#d62728", "#2ca02c", "#1f77b4"};
    static const char* names[3] = {"X", "Y", "Z"};
    for (const auto& [T, located] : frames) {
        const Eigen::Vector2d o = to_svg(T.translation());
        for (int a = 0; a < 3; ++a) {
            const Eigen::Vector2d e = to_svg(T * (axis_length * Eigen::Vector3d::Unit(a)));
            s << "<line x1='" << fixed(o.x(), 1) << "' y1='" << fixed(o.y(), 1) << "' x2='" << fixed(e.x(), 1)
              << "' y2='" << fixed(e.y(), 1) << "' stroke='" << colours[a] << "' stroke-width='"
              << (located ? 2.5 : 1.2) << "'" << (located ? "" : " stroke-dasharray='4 3'") << "/>";
            if (located && (e - o).norm() > 4)
                s << "<text x='" << fixed(e.x() + 3, 1) << "' y='" << fixed(e.y() - 3, 1) << "' fill='"
                  << colours[a] << "' font-size='11'>" << names[a] << "</text>";
        }
    }

    // Scale bar, bottom left.
    const double bar = round_length(0.25 * (W - 2 * margin) / scale);
    const double px = bar * scale;
    s << "<line x1='" << margin << "' y1='" << H - 10 << "' x2='" << fixed(margin + px, 1) << "' y2='"
      << H - 10 << "' stroke='#333' stroke-width='2'/><text x='" << fixed(margin + px + 5, 1) << "' y='"
      << H - 6 << "' font-size='11' fill='#333'>"
      << fixed(bar, std::max(0, -static_cast<int>(std::floor(std::log10(bar))))) << " "
      << escape_html(f.units) << "</text>";
    static const char* axis_names[3] = {"X", "Y", "Z"};
    s << "<text x='" << W - margin << "' y='" << H - 6 << "' font-size='11' fill='#333' text-anchor='end'>→ "
      << axis_names[v.right] << "  ↑ " << axis_names[v.up] << "</text>";
    s << "</svg><figcaption>" << v.title << "</figcaption></figure>";
    return s.str();
}

const char* kStyle = R"(
body{font-family:system-ui,-apple-system,"Segoe UI",Roboto,sans-serif;margin:24px;color:#222;max-width:1200px}
h1{font-size:1.5em;margin-bottom:4px} h2{font-size:1.2em;margin-top:28px;border-bottom:1px solid #ddd}
h3{font-size:1em;margin-bottom:4px}
table{border-collapse:collapse;margin:6px 0 12px 0;font-size:0.92em}
th,td{border:1px solid #ddd;padding:3px 8px;text-align:left;vertical-align:top}
th{background:#f2f2f2} td.num{text-align:right;font-variant-numeric:tabular-nums}
.banner{padding:10px 14px;border-radius:4px;font-size:1.15em;margin:12px 0}
.ok{background:#e3f4e3;border:1px solid #7cbf7c} .bad{background:#fbe4e4;border:1px solid #d98c8c}
.warn{background:#fff4d6;border:1px solid #e0a526}
.reg{color:#1b7a1b;font-weight:600} .rej{color:#b22222;font-weight:600} .dim{color:#777}
figure{display:inline-block;margin:0 12px 12px 0} figcaption{text-align:center;font-size:0.9em;color:#555}
.view3d .canvas{border:1px solid #ddd;display:inline-block;line-height:0} .view3d p{margin:4px 0}
.swatch{display:inline-block;width:12px;height:12px;border:1px solid #aaa;vertical-align:middle}
.ramp{display:inline-block;width:120px;height:12px;border:1px solid #aaa;vertical-align:middle}
)";

}  // namespace

std::string escape_html(const std::string& text) {
    std::string out;
    out.reserve(text.size());
    for (char c : text) {
        switch (c) {
            case '&':
                out += "&amp;";
                break;
            case '<':
                out += "&lt;";
                break;
            case '>':
                out += "&gt;";
                break;
            case '"':
                out += "&quot;";
                break;
            case '\'':
                out += "&#39;";
                break;
            default:
                out += c;
        }
    }
    return out;
}

/// The banner and the pose: what the machinist came for.
static void pose_section(std::ostream& h, const Job& job, const JobResult& result, const Formatter& f,
                         const std::string& u) {
    const WorkpieceResult& w = result.workpiece;
    std::size_t registered = 0;
    for (const auto& s : result.scans) registered += s.valid ? 1 : 0;
    if (result.workpiece.valid && !result.warnings.empty()) {
        h << "<div class='banner warn'><b>Workpiece located with warnings</b> from " << registered << " of "
          << result.scans.size() << " scans: look at them before cutting.<ul>";
        for (const auto& warning : result.warnings) h << "<li>" << escape_html(warning) << "</li>";
        h << "</ul></div>\n";
    } else if (result.workpiece.valid) {
        h << "<div class='banner ok'><b>Workpiece located</b> from " << registered << " of "
          << result.scans.size() << " scans.</div>\n";
    } else {
        h << "<div class='banner bad'><b>Workpiece not located.</b> " << escape_html(w.reason) << "</div>\n";
    }

    // The pose first: it is what the machinist came for.
    h << "<h2>Workpiece pose (machine frame, all axes at 0)</h2>\n";
    h << "<table><tr><th></th><th>X (" << u << ")</th><th>Y (" << u << ")</th><th>Z (" << u
      << ")</th><th>rot X (°)</th><th>rot Y (°)</th><th>rot Z (°)</th></tr>\n";
    const Eigen::Isometry3d& nominal = job.workpiece.T_machine_workpiece;
    h << "<tr><th>nominal (datum)</th>" << pose_cells(nominal, f) << "</tr>\n";
    if (w.valid) {
        h << "<tr><th>located</th>" << pose_cells(w.T_machine_workpiece, f) << "</tr>\n";
        const Eigen::Vector3d dt = w.T_machine_workpiece.translation() - nominal.translation();
        const Eigen::Vector3d el = euler_xyz_deg(w.T_machine_workpiece.linear()),
                              en = euler_xyz_deg(nominal.linear());
        h << "<tr><th>deviation (located − nominal)</th>";
        for (int i = 0; i < 3; ++i) h << "<td class=num><b>" << f.length(dt[i]) << "</b></td>";
        for (int i = 0; i < 3; ++i)
            h << "<td class=num><b>" << f.angle(wrap_deg(el[i] - en[i])) << "</b></td>";
        h << "</tr>\n";
        if (w.uncertainty.available) {
            h << "<tr><th>± 95 % (uncertainty)</th>";
            for (int i = 0; i < 3; ++i)
                h << "<td class=num>± " << f.length(w.uncertainty.origin[i]) << "</td>";
            for (int i = 0; i < 3; ++i)
                h << "<td class=num>± " << f.angle(w.uncertainty.euler_deg[i]) << "</td>";
            h << "</tr>\n";
        } else {
            h << "<tr><th>± 95 % (uncertainty)</th><td colspan=6 class=dim>not estimated (fewer than three "
                 "registered scans)</td></tr>\n";
        }
    } else {
        h << "<tr><th>located</th><td colspan=6 class=dim>not located</td></tr>\n";
    }
    h << "</table>\n";
    h << "<p class=dim>rot X, rot Y, rot Z: euler_xyz_deg, R = Rz(rot Z)·Ry(rot Y)·Rx(rot X), rotations "
         "about the machine X, then Y, then Z axes (not the machine's rotary axes, which the scans table "
         "names as \"axis A\"...).</p>\n";
    if (w.valid) {
        const PoseError e = pose_error(w.T_machine_workpiece, nominal);
        h << "<table><tr><th>shift from nominal</th><td class=num>" << f.length(e.translation) << " " << u
          << "</td></tr><tr><th>rotation from nominal</th><td class=num>" << f.angle(e.rotation_deg)
          << " °</td></tr><tr><th>fit rmse</th><td class=num>" << f.length(w.rmse) << " " << u
          << "</td></tr><tr><th>points the fit took</th><td class=num>" << w.points
          << "</td></tr><tr><th>of those on the reference surfaces</th><td class=num>" << w.inliers
          << "</td></tr></table>\n";
    }
}

/// One row per scan: status, fiducials, scale, time, reason and warnings.
static void scans_section(std::ostream& h, const Job& job, const JobResult& result, const Formatter& f,
                          const std::string& u) {
    h << "<h2>Scans</h2>\n<table><tr><th>#</th><th>file</th><th>axes</th><th>status</th><th>fiducials</th>"
         "<th>score</th><th>rmse ("
      << u << ")</th><th>points</th><th>spacing (" << u << ")</th><th>noise (" << u
      << ")</th><th>time (s)</th><th>message</th></tr>\n";
    for (std::size_t i = 0; i < result.scans.size(); ++i) {
        const ScanResult& s = result.scans[i];
        const Scan* scan = i < job.scans.size() ? &job.scans[i] : nullptr;
        std::string fids;
        for (const auto& name : s.fiducials) fids += (fids.empty() ? "" : ", ") + escape_html(name);
        h << "<tr><td class=num>" << i + 1 << "</td><td>"
          << escape_html(s.file.empty() && scan ? scan->file : s.file) << "</td><td>"
          << (scan ? axis_values(scan->axes) : "")
          << "</td><td class=" << (s.valid ? "reg>registered" : "rej>rejected") << "</td><td>" << fids
          << "</td><td class=num>" << fixed(s.score, 2) << "</td><td class=num>" << f.length(s.rmse)
          << "</td><td class=num>" << s.points << "</td><td class=num>" << f.length(s.point_spacing)
          << "</td><td class=num>" << f.length(s.noise) << "</td><td class=num>" << fixed(s.seconds, 2)
          << "</td><td>" << escape_html(s.reason);
        for (const auto& warning : s.warnings) h << "<br><b>warning:</b> " << escape_html(warning);
        h << "</td></tr>\n";
    }
    if (result.scans.empty()) h << "<tr><td colspan=12 class=dim>no scan results</td></tr>\n";
    h << "</table>\n<p class=dim><b>status</b>: registered (placed in the machine frame by the fiducials "
         "named) or rejected (the message says why). <b>score</b>: the winning fiducial fit's coverage × (1 "
         "− "
         "violation), 0 to 1 (see the next table). <b>rmse</b>: RMS distance of the fiducial's points to its "
         "model. <b>spacing</b>, <b>noise</b>: the scan's point spacing and 1-sigma noise, as the job gives "
         "them or measured on the scan.</p>\n";
}

/// Each scan's fiducial fits, accepted or rejected and why.
static void fits_section(std::ostream& h, const JobResult& result, const Formatter& f, const std::string& u) {
    const LocalizeSettings limits;  // the defaults the verification applies
    h << "<h2>Fiducials tried per scan</h2>\n<p class=dim><b>coverage</b>: the fraction of the model's "
         "surface facing the scanner that the scan shows (accepted from "
      << fixed(limits.min_coverage, 2)
      << "). <b>violation</b>: the fraction of the observed model surface the scanner saw through, points "
         "behind where the model would block the view (accepted up to "
      << fixed(limits.max_violation, 2)
      << "). <b>conditioning</b>: how well the points fix all six degrees of freedom, 0 (a plane alone) to "
         "0.33 (accepted from "
      << fixed(limits.min_conditioning, 3)
      << "). <b>inliers</b>: scan points on the model's surface. <b>score</b>: coverage × (1 − violation). "
         "\"where the others put it\": checked at the pose the scan's other fiducials give, not searched "
         "for.</p>\n";
    for (std::size_t i = 0; i < result.scans.size(); ++i) {
        const ScanResult& s = result.scans[i];
        h << "<h3>Scan " << i + 1 << ": " << escape_html(s.file) << "</h3>\n";
        if (s.fits.empty()) {
            h << "<p class=dim>No fiducial was tried.</p>\n";
            continue;
        }
        h << "<table><tr><th>fiducial</th><th>outcome</th><th>score</th><th>rmse (" << u
          << ")</th><th>coverage</th><th>violation</th><th>conditioning</th><th>inliers</th><th>reason</th></"
             "tr>\n";
        for (const FiducialFit& fit : s.fits)
            h << "<tr><td>" << escape_html(fit.fiducial)
              << "</td><td class=" << (fit.valid ? "reg>accepted" : "rej>rejected")
              << (fit.searched ? "" : " where the others put it") << "</td><td class=num>"
              << fixed(fit.score, 2) << "</td><td class=num>" << f.length(fit.rmse) << "</td><td class=num>"
              << fixed(fit.coverage, 3) << "</td><td class=num>" << fixed(fit.violation, 3)
              << "</td><td class=num>" << fixed(fit.conditioning, 4) << "</td><td class=num>" << fit.inliers
              << "</td><td>" << escape_html(fit.reason) << "</td></tr>\n";
        h << "</table>\n";
    }
}

/// Three orthographic views of the merged points with the nominal and located frames.
static void points_section(std::ostream& h, const Job& job, const JobResult& result, const Formatter& f,
                           const ReportOptions& options) {
    const WorkpieceResult& w = result.workpiece;
    const Eigen::Isometry3d& nominal = job.workpiece.T_machine_workpiece;
    h << "<h2>Merged workpiece points (machine frame, all axes at 0)</h2>\n";
    std::vector<Eigen::Vector3d> points;
    if (result.merged && !result.merged->points_.empty()) {
        const auto& all = result.merged->points_;
        const std::size_t stride = std::max<std::size_t>(
            1, (all.size() + options.max_points - 1) / std::max<std::size_t>(options.max_points, 1));
        for (std::size_t i = 0; i < all.size(); i += stride)
            if (all[i].allFinite()) points.push_back(all[i]);
    }
    if (points.empty() && !w.valid) {
        h << "<p class=dim>No merged points: no scan was registered.</p>\n";
    } else {
        Eigen::AlignedBox3d box;
        for (const auto& p : points) box.extend(p);
        double axis_length = points.empty() ? 0.0 : 0.2 * box.sizes().maxCoeff();
        if (!(axis_length > 0)) axis_length = 10.0 / millimetres_per_unit_or_one(job.units);
        std::vector<std::pair<Eigen::Isometry3d, bool>> frames = {{nominal, false}};
        if (w.valid) frames.push_back({w.T_machine_workpiece, true});
        h << "<p class=dim>" << points.size() << " of " << (result.merged ? result.merged->points_.size() : 0)
          << " points drawn, darker nearer. Workpiece frame: located solid, nominal dashed; X red, Y green, "
             "Z "
             "blue.</p>\n";
        const View views[3] = {{"Top (XY), looking down −Z", 0, 1, 2, 1.0},
                               {"Front (XZ), looking along +Y", 0, 2, 1, -1.0},
                               {"Side (YZ), looking along −X", 1, 2, 0, 1.0}};
        for (const View& v : views) h << svg_view(v, points, frames, axis_length, f) << "\n";
    }
}

/// What the job said: units, scanner, models, axes and fiducials.
static void job_section(std::ostream& h, const Job& job, const JobResult& result, const Formatter& f,
                        const std::string& u) {
    h << "<h2>Job</h2>\n<table>";
    h << "<tr><th>units</th><td>" << u << "</td></tr>";
    h << "<tr><th>scanner</th><td>point spacing "
      << (job.scanner.point_spacing ? f.length(*job.scanner.point_spacing) + " " + u : "estimated per scan")
      << ", noise " << (job.scanner.noise ? f.length(*job.scanner.noise) + " " + u : "estimated per scan")
      << "</td></tr>";
    h << "<tr><th>reference surfaces</th><td>" << model_summary(job.workpiece.reference_surfaces)
      << "</td></tr>";
    if (job.workpiece.final_part)
        h << "<tr><th>final part</th><td>" << model_summary(*job.workpiece.final_part) << "</td></tr>";
    h << "<tr><th>workpiece moves with</th><td>" << chain(job.workpiece.moves_with) << "</td></tr>";
    if (job.workpiece.region)
        h << "<tr><th>region</th><td>min [" << f.vec(job.workpiece.region->min()) << "], max ["
          << f.vec(job.workpiece.region->max()) << "] " << u << "</td></tr>";
    h << "<tr><th>total time</th><td>" << fixed(result.seconds, 2) << " s</td></tr></table>\n";

    if (!job.machine.axes.empty()) {
        h << "<h3>Machine axes</h3><table><tr><th>name</th><th>type</th><th>direction</th><th>point (" << u
          << ")</th></tr>";
        for (const Axis& a : job.machine.axes)
            h << "<tr><td>" << escape_html(a.name) << "</td><td>"
              << (a.type == AxisType::Rotary ? "rotary (°)" : "linear (" + u + ")") << "</td><td>"
              << fixed(a.direction.x(), 4) << ", " << fixed(a.direction.y(), 4) << ", "
              << fixed(a.direction.z(), 4) << "</td><td>"
              << (a.type == AxisType::Rotary ? f.vec(a.point) : "") << "</td></tr>";
        h << "</table>\n";
    }
    h << "<h3>Fiducials</h3><table><tr><th>name</th><th>model</th><th>origin (" << u
      << ")</th><th>euler_xyz_deg</th><th>probed at</th><th>moves with</th></tr>";
    for (const Fiducial& fid : job.fiducials)
        h << "<tr><td>" << escape_html(fid.name) << "</td><td>" << model_summary(fid.model) << "</td><td>"
          << f.vec(fid.T_machine_fiducial.translation()) << "</td><td>"
          << f.vec(euler_xyz_deg(fid.T_machine_fiducial.linear()), true) << "</td><td>"
          << axis_values(fid.probed_at) << "</td><td>" << chain(fid.moves_with) << "</td></tr>";
    h << "</table>\n";
}

/// SPEC "Machining": the final part's allowance per face and its placement.
static void machining_section(std::ostream& h, const JobResult& result, const Formatter& f,
                              const std::string& u) {
    const MachiningResult& m = result.machining;
    if (!m.available) {
        if (!m.reason.empty()) h << "<h2>Allowance</h2>\n<p class=dim>" << escape_html(m.reason) << "</p>\n";
        return;
    }
    const auto cell = [&](double v) {
        return std::isnan(v) ? std::string("<td class=dim>unscanned</td>")
                             : "<td class=num" + std::string(v < m.required ? " style='color:#b00'" : "") +
                                   ">" + f.length(v) + "</td>";
    };
    h << "<h2>Allowance: the stock left on the final part</h2>\n";
    h << "<p>Placement <b>" << (m.maxmin ? "maxmin" : "located") << "</b>: <b>"
      << (m.fits ? "fits" : "insufficient stock") << "</b>; least allowance " << f.length(m.map.all.min)
      << " " << u << " (required " << f.length(m.required) << " " << u << "; " << f.length(m.located.all.min)
      << " " << u << " where the part was located); moved " << f.length(m.translation) << " " << u << " and "
      << f.angle(m.rotation_deg) << " ° from the located frame.</p>\n";
    h << "<table><tr><th>placed frame</th><th>X (" << u << ")</th><th>Y (" << u << ")</th><th>Z (" << u
      << ")</th><th>rot X (°)</th><th>rot Y (°)</th><th>rot Z (°)</th></tr>\n<tr><th>T_machine_part</th>"
      << pose_cells(m.T_machine_part, f) << "</tr></table>\n";
    h << "<table><tr><th>face</th><th>area (" << u << "²)</th><th>min (" << u << ")</th><th>mean (" << u
      << ")</th><th>max (" << u << ")</th><th>unscanned</th></tr>\n";
    for (std::size_t k = 0; k < m.map.faces.size(); ++k) {
        const FaceAllowance& a = m.map.faces[k];
        h << "<tr><td>" << escape_html(m.face_names[k]) << "</td><td class=num>"
          << fixed(m.part.faces[k].area, 1) << "</td>" << cell(a.min) << cell(a.mean) << cell(a.max)
          << "<td class=num>" << fixed(100.0 * a.unscanned_fraction(), 1) << " %</td></tr>\n";
    }
    h << "</table>\n<p class=dim>Allowance: the distance along the final part's outward normal to the "
         "scanned "
         "surface, positive where stock remains, red below the required; unscanned where no scan saw the "
         "stock. Per sample in allowance.ply.</p>\n";
}

std::string render_report_html(const Job& job, const JobResult& result, const ReportOptions& options) {
    const Formatter f{length_decimals(job.units), job.units};
    const std::string u = escape_html(job.units);
    const std::string title =
        "partloc report" + (options.job_name.empty() ? "" : ": " + escape_html(options.job_name));
    std::ostringstream h;
    h << "<!DOCTYPE html>\n<html lang='en'><head><meta charset='utf-8'><title>" << title << "</title><style>"
      << kStyle << "</style></head><body>\n<h1>" << title << "</h1>\n";
    pose_section(h, job, result, f, u);
    h << view3d_section(job, result, options.view3d);
    machining_section(h, result, f, u);
    scans_section(h, job, result, f, u);
    fits_section(h, result, f, u);
    points_section(h, job, result, f, options);
    job_section(h, job, result, f, u);
    h << "</body></html>\n";
    return h.str();
}

}  // namespace partloc::io
