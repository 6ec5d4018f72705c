#include "partloc/io/report_view3d.hpp"

#include <openssl/evp.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <nlohmann/json.hpp>
#include <sstream>

#include "partloc/io/formats.hpp"
#include "partloc/io/report_html.hpp"

#ifndef PARTLOC_THREE_JS_DIR
#define PARTLOC_THREE_JS_DIR "/usr/share/javascript/three"
#endif

namespace partloc::io {

namespace fs = std::filesystem;

namespace {

using Json = nlohmann::ordered_json;

/// Base64 of the array's bytes (the page's arrays; atob decodes them), by OpenSSL's encoder.
template <class T>
std::string base64(const std::vector<T>& v) {
    const std::size_t n = v.size() * sizeof(T);
    std::string out(4 * ((n + 2) / 3) + 1, '\0');
    const int written =
        EVP_EncodeBlock(reinterpret_cast<unsigned char*>(out.data()),
                        reinterpret_cast<const unsigned char*>(v.data()), static_cast<int>(n));
    out.resize(static_cast<std::size_t>(written));
    return out;
}

/// The file's bytes, or false when it cannot be read (a missing three.js leaves the page without the view).
bool read_file(const fs::path& path, std::string& text) {
    try {
        text = detail::read_file_bytes(path, path.string());
    } catch (const InputError&) {
        return false;
    }
    return !text.empty();
}

/// A script's text safe inside <script>: "</script" cannot occur in it.
std::string script_safe(std::string text) {
    std::size_t at = 0;
    while ((at = text.find("</", at)) != std::string::npos) {
        text.replace(at, 2, "<\\/");
        at += 3;
    }
    return text;
}

/// Coordinates relative to `centre`, as float32 (machine coordinates of a metre keep 0.1 µm).
void put(std::vector<float>& out, const Eigen::Vector3d& p, const Eigen::Vector3d& centre) {
    for (int k = 0; k < 3; ++k) out.push_back(static_cast<float>(p[k] - centre[k]));
}

Json frame_json(const Eigen::Isometry3d& T, const Eigen::Vector3d& centre) {
    Json j = Json::array();  // origin, then the three axis directions
    const Eigen::Vector3d o = T.translation() - centre;
    j.push_back({o.x(), o.y(), o.z()});
    for (int a = 0; a < 3; ++a) {
        const Eigen::Vector3d e = T.linear().col(a);
        j.push_back({e.x(), e.y(), e.z()});
    }
    return j;
}

/// The deviation's colour scale: the larger of three times the scans' noise and the 95th percentile of
/// |deviation|, so that noise shows pale and a bias or a misfit shows in full colour.
double deviation_scale(const ViewPoints& v, double noise) {
    std::vector<float> a;
    for (float d : v.deviation)
        if (std::isfinite(d)) a.push_back(std::abs(d));
    double p95 = 0.0;
    if (!a.empty()) {
        const std::size_t k = static_cast<std::size_t>(0.95 * static_cast<double>(a.size() - 1));
        std::nth_element(a.begin(), a.begin() + static_cast<std::ptrdiff_t>(k), a.end());
        p95 = a[k];
    }
    const double s = std::max(3.0 * noise, p95);
    return s > 0 ? s : 1.0;
}

// The page's script: reads the data, draws, and records the outcome on #view3d for the browser test.
const char* kScript = R"JS(
(function () {
  var el = document.getElementById('view3d');
  function mark(k, v) { el.setAttribute('data-' + k, String(v)); }
  window.addEventListener('error', function (e) { mark('error', e.message); });
  try {
    var D = JSON.parse(document.getElementById('view3d-data').textContent);
    function arr(s, T) {
      var bin = atob(s), u = new Uint8Array(bin.length);
      for (var i = 0; i < bin.length; ++i) u[i] = bin.charCodeAt(i);
      return new T(u.buffer);
    }
    var W = Math.max(320, Math.min(el.clientWidth || 960, 1200)), H = Math.round(W * 0.6);
    var renderer = new THREE.WebGLRenderer({antialias: true, preserveDrawingBuffer: true});
    renderer.setPixelRatio(window.devicePixelRatio || 1);
    renderer.setSize(W, H);
    el.querySelector('.canvas').appendChild(renderer.domElement);
    var scene = new THREE.Scene();
    scene.background = new THREE.Color(0xffffff);
    scene.add(new THREE.AmbientLight(0xffffff, 0.6));
    var sun = new THREE.DirectionalLight(0xffffff, 0.5);
    sun.position.set(1, -1.5, 2);
    scene.add(sun);
    var size = D.size > 0 ? D.size : 1;
    var camera = new THREE.PerspectiveCamera(35, W / H, size / 1000, size * 100);
    camera.up.set(0, 0, 1);
    camera.position.set(0.9 * size, -1.1 * size, 0.8 * size);
    camera.lookAt(0, 0, 0);
    var vc = THREE.VertexColors !== undefined ? THREE.VertexColors : true;
    function points(pos, colours, px) {
      var g = new THREE.BufferGeometry();
      g.setAttribute('position', new THREE.BufferAttribute(pos, 3));
      g.setAttribute('color', new THREE.BufferAttribute(colours, 3));
      return new THREE.Points(g, new THREE.PointsMaterial({size: px, sizeAttenuation: false, vertexColors: vc}));
    }
    var layers = {};
    // Scan points: by scan, or by deviation from the located reference surfaces.
    var P = D.points ? arr(D.points, Float32Array) : new Float32Array(0);
    var S = D.scan ? arr(D.scan, Uint16Array) : new Uint16Array(0);
    var E = D.deviation ? arr(D.deviation, Float32Array) : new Float32Array(0);
    var palette = [[0.12,0.47,0.71],[1.0,0.5,0.05],[0.17,0.63,0.17],[0.84,0.15,0.16],[0.58,0.4,0.74],
                   [0.55,0.34,0.29],[0.89,0.47,0.76],[0.5,0.5,0.5],[0.74,0.74,0.13],[0.09,0.75,0.81]];
    var byScan = new Float32Array(P.length), byDev = new Float32Array(P.length);
    for (var i = 0; i < S.length; ++i) {
      var c = palette[S[i] % palette.length];
      byScan.set(c, 3 * i);
      var d = E[i];
      if (!isFinite(d)) { byDev.set([0.8, 0.8, 0.8], 3 * i); continue; }
      var t = Math.max(-1, Math.min(1, d / D.deviation_scale));
      byDev.set(t >= 0 ? [1, 1 - 0.85 * t, 1 - 0.85 * t] : [1 + 0.85 * t, 1 + 0.85 * t, 1], 3 * i);
    }
    if (P.length) { layers.scans = points(P, byScan, 2); scene.add(layers.scans); }
    // The reference surfaces where they were located.
    if (D.reference) {
      var g = new THREE.BufferGeometry();
      g.setAttribute('position', new THREE.BufferAttribute(arr(D.reference.vertices, Float32Array), 3));
      if (D.reference.triangles) {
        g.setIndex(new THREE.BufferAttribute(arr(D.reference.triangles, Uint32Array), 1));
        g.computeVertexNormals();
        layers.reference = new THREE.Mesh(g, new THREE.MeshLambertMaterial(
            {color: 0x8899aa, transparent: true, opacity: 0.35, side: THREE.DoubleSide, depthWrite: false}));
      } else {
        layers.reference = new THREE.Points(g, new THREE.PointsMaterial({size: 1, sizeAttenuation: false, color: 0x8899aa}));
      }
      scene.add(layers.reference);
    }
    // The final part's allowance: red where it breaks out, grey where unscanned, green to blue to 2x mean.
    if (D.allowance) {
      var AP = arr(D.allowance.points, Float32Array), AV = arr(D.allowance.values, Float32Array);
      var AC = new Float32Array(AP.length), top = D.allowance.top;
      for (var i = 0; i < AV.length; ++i) {
        var a = AV[i];
        if (!isFinite(a)) AC.set([0.6, 0.6, 0.6], 3 * i);
        else if (a < D.allowance.required) AC.set([0.86, 0.12, 0.12], 3 * i);
        else { var t = Math.max(0, Math.min(1, a / top)); AC.set([0.08, 0.94 * (1 - t) + 0.16, 0.84 * t + 0.16], 3 * i); }
      }
      layers.allowance = points(AP, AC, 3);
      scene.add(layers.allowance);
    }
    // Frames: located solid, nominal dashed; X red, Y green, Z blue.
    layers.frames = new THREE.Group();
    var axisColours = [0xd62728, 0x2ca02c, 0x1f77b4];
    (D.frames || []).forEach(function (f) {
      for (var a = 0; a < 3; ++a) {
        var o = new THREE.Vector3().fromArray(f.axes[0]);
        var e = o.clone().addScaledVector(new THREE.Vector3().fromArray(f.axes[a + 1]), D.axis_length);
        var g = new THREE.BufferGeometry().setFromPoints([o, e]);
        var m = f.located ? new THREE.LineBasicMaterial({color: axisColours[a]})
                          : new THREE.LineDashedMaterial({color: axisColours[a], dashSize: D.axis_length / 12, gapSize: D.axis_length / 12});
        var line = new THREE.Line(g, m);
        if (!f.located) line.computeLineDistances();
        layers.frames.add(line);
      }
    });
    scene.add(layers.frames);

    function render() { renderer.render(scene, camera); }
    var controls = new THREE.OrbitControls(camera, renderer.domElement);
    controls.target.set(0, 0, 0);
    controls.addEventListener('change', render);
    controls.update();
    // The controls under the canvas.
    var legend = el.querySelector('.legend');
    function showLegend() {
      var mode = el.querySelector('input[name=view3d-colour]:checked');
      mode = mode ? mode.value : 'scan';
      if (layers.scans) {
        layers.scans.geometry.attributes.color.array.set(mode === 'deviation' ? byDev : byScan);
        layers.scans.geometry.attributes.color.needsUpdate = true;
      }
      legend.querySelector('.scan').style.display = mode === 'scan' ? '' : 'none';
      legend.querySelector('.deviation').style.display = mode === 'deviation' ? '' : 'none';
      render();
    }
    el.querySelectorAll('input[name=view3d-colour]').forEach(function (r) { r.addEventListener('change', showLegend); });
    el.querySelectorAll('input[data-layer]').forEach(function (box) {
      var layer = layers[box.getAttribute('data-layer')];
      if (!layer) { box.disabled = true; box.checked = false; return; }
      box.addEventListener('change', function () { layer.visible = box.checked; render(); });
    });
    showLegend();
    // What the browser test reads: the pixels of the first frame that are not the background.
    var gl = renderer.getContext(), w = gl.drawingBufferWidth, h = gl.drawingBufferHeight;
    var px = new Uint8Array(w * h * 4), drawn = 0;
    gl.readPixels(0, 0, w, h, gl.RGBA, gl.UNSIGNED_BYTE, px);
    for (var i = 0; i < px.length; i += 4) if (px[i] < 250 || px[i + 1] < 250 || px[i + 2] < 250) ++drawn;
    mark('drawn', drawn);
    var box = renderer.domElement.getBoundingClientRect();
    mark('rect', [box.left + window.scrollX, box.top + window.scrollY, box.width, box.height].map(Math.round).join(' '));
  } catch (e) {
    mark('error', e && e.message ? e.message : e);
  }
})();
)JS";

}  // namespace

fs::path View3dOptions::default_three_js_dir() {
    const char* env = std::getenv("PARTLOC_THREE_JS_DIR");
    return env && *env ? fs::path(env) : fs::path(PARTLOC_THREE_JS_DIR);
}

std::string view3d_section(const Job& job, const JobResult& result, const View3dOptions& options) {
    std::ostringstream h;
    h << "<h2 id=view3d-title>3D view (machine frame, all axes at 0)</h2>\n";
    std::string three, orbit;
    const fs::path three_path = options.three_js_dir / "three.min.js";
    const fs::path orbit_path = options.three_js_dir / "examples" / "js" / "controls" / "OrbitControls.js";
    if (!read_file(three_path, three) || !read_file(orbit_path, orbit)) {
        h << "<p class=dim>No 3D view: it needs three.js (Debian's package libjs-three), not found at "
          << escape_html(options.three_js_dir.string())
          << ". The pictures further down show the same points.</p>\n";
        return h.str();
    }
    const ViewPoints& v = result.view;
    const MachiningResult& m = result.machining;
    const WorkpieceResult& w = result.workpiece;

    // The scene's centre and size: the points, else the reference surfaces' nominal place.
    Eigen::AlignedBox3d box;
    for (const auto& p : v.points) box.extend(p.cast<double>());
    if (m.available)
        for (const auto& p : m.map.points) box.extend(p);
    if (box.isEmpty()) box.extend(job.workpiece.T_machine_workpiece.translation());
    const Eigen::Vector3d centre = box.center();
    const double size = std::max(box.sizes().maxCoeff(), 1e-9);

    Json d;
    d["units"] = job.units;
    d["size"] = size;
    d["axis_length"] = 0.25 * size;
    Json scans = Json::array();
    for (const ScanResult& s : result.scans) scans.push_back(s.file);
    d["scans"] = scans;
    if (!v.points.empty()) {
        std::vector<float> pos;
        pos.reserve(3 * v.points.size());
        for (const auto& p : v.points) put(pos, p.cast<double>(), centre);
        std::vector<std::uint16_t> scan;
        for (int s : v.scan) scan.push_back(static_cast<std::uint16_t>(std::clamp(s, 0, 65535)));
        d["points"] = base64(pos);
        d["scan"] = base64(scan);
        d["deviation"] = base64(v.deviation);
        double noise = 0.0;
        for (const ScanResult& s : result.scans)
            if (s.valid) noise = std::max(noise, s.noise);
        d["deviation_scale"] = deviation_scale(v, noise);
    }
    // The reference surfaces, moved where they were located (nominal where the part was not located).
    const Eigen::Isometry3d T_located_nominal =
        w.valid ? Eigen::Isometry3d(w.T_machine_workpiece * w.T_machine_workpiece_nominal.inverse())
                : Eigen::Isometry3d::Identity();
    const ModelSource& ref = job.workpiece.reference_surfaces;
    if (ref.mesh && !ref.mesh->vertices_.empty()) {
        std::vector<float> vertices;
        for (const auto& p : ref.mesh->vertices_) put(vertices, T_located_nominal * p, centre);
        Json r;
        r["vertices"] = base64(vertices);
        if (ref.mesh->triangles_.size() <= options.max_triangles) {
            std::vector<std::uint32_t> tri;
            for (const auto& t : ref.mesh->triangles_)
                for (int k = 0; k < 3; ++k) tri.push_back(static_cast<std::uint32_t>(t[k]));
            r["triangles"] = base64(tri);
        }
        d["reference"] = r;
    } else if (ref.points && !ref.points->points_.empty()) {
        std::vector<float> vertices;
        for (const auto& p : ref.points->points_) put(vertices, T_located_nominal * p, centre);
        d["reference"] = {{"vertices", base64(vertices)}};
    }
    if (m.available && !m.map.points.empty()) {
        const std::size_t n = m.map.points.size();
        const std::size_t stride =
            std::max<std::size_t>(1, (n + options.max_allowance_points - 1) /
                                         std::max<std::size_t>(options.max_allowance_points, 1));
        std::vector<float> pos, val;
        for (std::size_t i = 0; i < n; i += stride) {
            put(pos, m.map.points[i], centre);
            val.push_back(static_cast<float>(m.map.allowance[i]));
        }
        const double top = std::isfinite(m.map.all.mean) && m.map.all.mean > 0 ? 2.0 * m.map.all.mean : 1.0;
        d["allowance"] = {
            {"points", base64(pos)}, {"values", base64(val)}, {"required", m.required}, {"top", top}};
    }
    Json frames = Json::array();
    frames.push_back({{"located", false}, {"axes", frame_json(job.workpiece.T_machine_workpiece, centre)}});
    if (w.valid) {
        const Eigen::Isometry3d& T = m.available ? m.T_machine_part : w.T_machine_workpiece;
        frames.push_back({{"located", true}, {"axes", frame_json(T, centre)}});
    }
    d["frames"] = frames;
    // '<' never appears outside JSON strings; inside them \u003c reads the same. So the data cannot end
    // the <script> element whatever a file name holds.
    std::string data = d.dump(-1, ' ', false, Json::error_handler_t::replace);
    for (std::size_t at = 0; (at = data.find('<', at)) != std::string::npos;) data.replace(at, 1, "\\u003c");

    const auto fmt = [&](double x) {
        char b[32];
        std::snprintf(b, sizeof b, "%.3g", x);
        return std::string(b);
    };
    const double dev_scale = d.contains("deviation_scale") ? d["deviation_scale"].get<double>() : 1.0;
    const std::string u = escape_html(job.units);
    h << "<div id=view3d class=view3d><div class=canvas></div>\n<p class=controls>Colour the scan points by "
         "<label><input type=radio name=view3d-colour value=scan checked> scan</label> "
         "<label><input type=radio name=view3d-colour value=deviation> deviation from the reference "
         "surfaces</label>. Show "
         "<label><input type=checkbox data-layer=scans checked> scan points</label> "
         "<label><input type=checkbox data-layer=reference checked> reference surfaces</label> "
         "<label><input type=checkbox data-layer=allowance checked> final part's allowance</label> "
         "<label><input type=checkbox data-layer=frames checked> workpiece frames</label></p>\n"
         "<div class=legend><p class=scan>";
    const char* palette[] = {"#1f78b5", "#ff800d", "#2ba12b", "#d62629", "#9466bd",
                             "#8c574a", "#e378c2", "#808080", "#bdbd21", "#17bfcf"};
    for (std::size_t i = 0; i < result.scans.size(); ++i) {
        const ScanResult& s = result.scans[i];
        if (!s.valid) continue;
        h << "<span class=swatch style='background:" << palette[i % 10] << "'></span> scan " << i + 1 << " "
          << escape_html(fs::path(s.file).filename().string()) << " &nbsp; ";
    }
    h << "</p><p class=deviation style='display:none'>Deviation of the scan points from the located "
         "reference "
         "surfaces, along their outward normal: "
      << "<span class=ramp style='background:linear-gradient(to right,#2626ff,#fff,#ff2626)'></span> "
      << "−" << fmt(dev_scale) << " … 0 … +" << fmt(dev_scale) << " " << u
      << " (blue inside the reference, red outside; grey: no reference surface within " << fmt(v.reach) << " "
      << u << ")</p>";
    if (m.available) {
        const double top = std::isfinite(m.map.all.mean) && m.map.all.mean > 0 ? 2.0 * m.map.all.mean : 1.0;
        h << "<p>Final part's allowance: <span class=swatch style='background:#dc1f1f'></span> below "
          << fmt(m.required) << " " << u
          << " (breaks out) <span class=ramp style='background:linear-gradient(to right,#14a829,#1429e3)'>"
             "</span> "
          << fmt(m.required) << " … " << fmt(top) << " " << u
          << " <span class=swatch style='background:#999'></span> unscanned</p>";
    }
    h << "<p class=dim>Drag to turn, wheel to zoom, right-drag to pan. Workpiece frames: "
      << (m.available && m.maxmin ? "placed" : "located")
      << " solid, nominal dashed; X red, Y green, Z blue.</p></div></div>\n";
    h << "<script type='application/json' id=view3d-data>" << data << "</script>\n";
    h << "<script>" << script_safe(three) << "\n</script>\n<script>" << script_safe(orbit) << "\n</script>\n";
    h << "<script>" << kScript << "</script>\n";
    return h.str();
}

}  // namespace partloc::io
