// partloc_world2: a second scene generator for partloc's trials (issue 25, item 6), written apart from
// partloc's own simulator: it shares no code with src/partloc/sim and uses partloc only through its files.
// It builds a cell from meshes (fiducials of four families, a vise or clamps, a second part, a fixture, a
// pallet, a near-net-shape workpiece with extra stock), scans it with a pinhole camera and a projector
// (a point only where both see it, cast with Embree), with depth noise, depth bias, smoothing, edge dropout,
// a scale error and outliers, and writes a job (job.yaml, models, scans) and truth.json.
#include <embree3/rtcore.h>

#include <Eigen/Dense>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <map>
#include <nlohmann/json.hpp>
#include <random>
#include <sstream>
#include <string>
#include <vector>

namespace fs = std::filesystem;
using Eigen::Isometry3d;
using Eigen::Matrix3d;
using Eigen::Vector2d;
using Eigen::Vector3d;
using json = nlohmann::json;

namespace {

constexpr double kPi = 3.14159265358979323846;
double deg(double d) { return d * kPi / 180.0; }

// ---------------------------------------------------------------- random numbers (deterministic per seed)
struct Rng {
    std::mt19937_64 g;
    explicit Rng(uint64_t s) : g(s * 0x9E3779B97F4A7C15ull + 12345) {}
    double uni(double a, double b) { return a + (b - a) * (double((g() >> 11)) / double(1ull << 53)); }
    double gauss() {  // Box-Muller, own code so the stream is the same on every standard library
        double u1 = uni(1e-12, 1.0), u2 = uni(0.0, 1.0);
        return std::sqrt(-2.0 * std::log(u1)) * std::cos(2 * kPi * u2);
    }
    int integer(int a, int b) { return a + int(g() % uint64_t(b - a + 1)); }
    bool chance(double p) { return uni(0, 1) < p; }
};

// ---------------------------------------------------------------- meshes
struct Mesh {
    std::vector<Vector3d> v;
    std::vector<std::array<int, 3>> f;
    void add(const Mesh& m, const Isometry3d& T = Isometry3d::Identity()) {
        int o = int(v.size());
        for (auto& p : m.v) v.push_back(T * p);
        for (auto& t : m.f) f.push_back({t[0] + o, t[1] + o, t[2] + o});
    }
    Mesh transformed(const Isometry3d& T) const {
        Mesh r;
        r.add(*this, T);
        return r;
    }
    Mesh mirrored_x() const {  // x -> -x, triangles flipped so they still face out
        Mesh r = *this;
        for (auto& p : r.v) p.x() = -p.x();
        for (auto& t : r.f) std::swap(t[1], t[2]);
        return r;
    }
};

// Hexahedron from 8 corners: b[0..3] bottom counter-clockwise seen from above, t[0..3] the top above them.
Mesh hexa(const std::array<Vector3d, 4>& b, const std::array<Vector3d, 4>& t) {
    Mesh m;
    for (auto& p : b) m.v.push_back(p);
    for (auto& p : t) m.v.push_back(p);
    auto quad = [&](int a, int b_, int c, int d) {
        m.f.push_back({a, b_, c});
        m.f.push_back({a, c, d});
    };
    quad(0, 3, 2, 1);  // bottom, facing down
    quad(4, 5, 6, 7);  // top
    quad(0, 1, 5, 4);
    quad(1, 2, 6, 5);
    quad(2, 3, 7, 6);
    quad(3, 0, 4, 7);
    return m;
}
Mesh box(Vector3d lo, Vector3d hi) {
    return hexa({Vector3d(lo.x(), lo.y(), lo.z()), Vector3d(hi.x(), lo.y(), lo.z()),
                 Vector3d(hi.x(), hi.y(), lo.z()), Vector3d(lo.x(), hi.y(), lo.z())},
                {Vector3d(lo.x(), lo.y(), hi.z()), Vector3d(hi.x(), lo.y(), hi.z()),
                 Vector3d(hi.x(), hi.y(), hi.z()), Vector3d(lo.x(), hi.y(), hi.z())});
}
// Frustum: bottom rectangle [x0,x1]x[y0,y1] at z0, top rectangle [u0,u1]x[v0,v1] at z1.
Mesh frustum(double x0, double x1, double y0, double y1, double z0, double u0, double u1, double v0,
             double v1, double z1) {
    return hexa({Vector3d(x0, y0, z0), Vector3d(x1, y0, z0), Vector3d(x1, y1, z0), Vector3d(x0, y1, z0)},
                {Vector3d(u0, v0, z1), Vector3d(u1, v0, z1), Vector3d(u1, v1, z1), Vector3d(u0, v1, z1)});
}

double cross2(Vector2d a, Vector2d b) { return a.x() * b.y() - a.y() * b.x(); }
// Ear clipping of a simple counter-clockwise polygon.
std::vector<std::array<int, 3>> triangulate(const std::vector<Vector2d>& p) {
    std::vector<int> idx(p.size());
    for (size_t i = 0; i < p.size(); ++i) idx[i] = int(i);
    std::vector<std::array<int, 3>> out;
    int guard = 0;
    while (idx.size() > 3 && guard++ < 10000) {
        bool cut = false;
        for (size_t i = 0; i < idx.size(); ++i) {
            int a = idx[(i + idx.size() - 1) % idx.size()], b = idx[i], c = idx[(i + 1) % idx.size()];
            if (cross2(p[b] - p[a], p[c] - p[b]) <= 1e-12) continue;
            bool inside = false;
            for (int j : idx) {
                if (j == a || j == b || j == c) continue;
                if (cross2(p[b] - p[a], p[j] - p[a]) >= 0 && cross2(p[c] - p[b], p[j] - p[b]) >= 0 &&
                    cross2(p[a] - p[c], p[j] - p[c]) >= 0) {
                    inside = true;
                    break;
                }
            }
            if (inside) continue;
            out.push_back({a, b, c});
            idx.erase(idx.begin() + long(i));
            cut = true;
            break;
        }
        if (!cut) break;
    }
    if (idx.size() == 3) out.push_back({idx[0], idx[1], idx[2]});
    return out;
}
// Prism: a counter-clockwise polygon in xy extruded from z0 to z1.
Mesh prism(const std::vector<Vector2d>& poly, double z0, double z1) {
    Mesh m;
    int n = int(poly.size());
    for (auto& q : poly) m.v.push_back(Vector3d(q.x(), q.y(), z0));
    for (auto& q : poly) m.v.push_back(Vector3d(q.x(), q.y(), z1));
    for (auto& t : triangulate(poly)) {
        m.f.push_back({t[0], t[2], t[1]});
        m.f.push_back({t[0] + n, t[1] + n, t[2] + n});
    }
    for (int i = 0; i < n; ++i) {
        int j = (i + 1) % n;
        m.f.push_back({i, j, j + n});
        m.f.push_back({i, j + n, i + n});
    }
    return m;
}
Isometry3d pose(Vector3d t, double rx_deg, double ry_deg, double rz_deg) {
    Isometry3d T = Isometry3d::Identity();
    T.linear() = (Eigen::AngleAxisd(deg(rz_deg), Vector3d::UnitZ()) *
                  Eigen::AngleAxisd(deg(ry_deg), Vector3d::UnitY()) *
                  Eigen::AngleAxisd(deg(rx_deg), Vector3d::UnitX()))
                     .toRotationMatrix();
    T.translation() = t;
    return T;
}

// ---------------------------------------------------------------- fiducial families (frame: datum corner at
// the origin, the block in +x +y +z, resting on z = 0). None has a mirror symmetry, so a mirrored copy is a
// look-alike, not the same shape.
Mesh fid_stepped(Rng& r, std::string& desc) {
    double L = r.uni(45, 70), W = r.uni(35, 55), h1 = r.uni(12, 20);
    double a = r.uni(14, 22), b = r.uni(14, W * 0.55), h2 = r.uni(h1 + 14, h1 + 26);
    double c = r.uni(8, 12), h3 = r.uni(h1 + 5, h2 - 5);
    Mesh m = box({0, 0, 0}, {L, W, h1});
    m.add(box({0, 0, 0}, {a, b, h2}));  // overlapping bodies: internal faces
    m.add(box({0, 0, 0}, {c, W, h3}));
    desc = "stepped block (three overlapping boxes, internal faces)";
    return m;
}
Mesh fid_notched(Rng& r, std::string& desc) {
    double L = r.uni(45, 65), W = r.uni(35, 50), H = r.uni(22, 35), ch = r.uni(7, 12);
    double n0 = r.uni(12, 20), nw = r.uni(8, 14), nd = r.uni(7, 12);
    // outline: a chamfer at (L, W), a notch in the y = 0 side
    std::vector<Vector2d> poly = {{0, 0}, {n0, 0},     {n0, nd},    {n0 + nw, nd}, {n0 + nw, 0},
                                  {L, 0}, {L, W - ch}, {L - ch, W}, {0, W}};
    Mesh m = prism(poly, 0, H);
    // a ramp on top along the x = 0 side: breaks the mirror plane z = H/2 and makes the block chiral
    double rl = r.uni(12, 18), rh = r.uni(6, 10);
    std::vector<Vector2d> tri = {{0, 0}, {rl, 0}, {0, rh}};
    Mesh ramp = prism(tri, 0, W * 0.6);  // in the ramp's frame: xy is the profile, z the length
    Isometry3d T = Isometry3d::Identity();
    T.linear() << 1, 0, 0, 0, 0, 1, 0, -1, 0;  // profile y -> z, length -> -y ... then shift
    T.linear() = Matrix3d(Eigen::AngleAxisd(kPi / 2, Vector3d::UnitX()));
    T.translation() = Vector3d(0, W * 0.6 + 2, H);
    m.add(ramp, T);
    desc = "notched and chamfered block with a ramp";
    return m;
}
Mesh fid_pyramid(Rng& r, std::string& desc) {
    double L = r.uni(45, 65), W = r.uni(32, 45), hb = r.uni(8, 14), hp = r.uni(18, 28);
    double tx = r.uni(8, 14), ty = r.uni(6, 10), ox = r.uni(0.15, 0.3) * L, oy = r.uni(0.15, 0.3) * W;
    Mesh m = box({0, 0, 0}, {L, W, hb});
    double u0 = ox + L * 0.2, v0 = oy + W * 0.2;
    m.add(frustum(3, L - 3, 3, W - 3, hb, u0, u0 + tx, v0, v0 + ty, hb + hp));  // oblique, off-centre top
    // a wedge on the +x end
    double wl = r.uni(10, 16), wh = r.uni(hb + 4, hb + 10);
    std::vector<Vector2d> prof = {{0, 0}, {wl, 0}, {0, wh}};
    Isometry3d T = Isometry3d::Identity();
    T.linear() = Matrix3d(Eigen::AngleAxisd(kPi / 2, Vector3d::UnitX()));
    T.translation() = Vector3d(L, W * 0.45, 0);
    m.add(prism(prof, 0, W * 0.45), T);
    desc = "oblique pyramid on a plinth with a wedge";
    return m;
}
Mesh fid_multibody(Rng& r, std::string& desc) {
    double L = r.uni(50, 70), W = r.uni(30, 45), h = r.uni(10, 16), t = r.uni(10, 15), H = r.uni(35, 50);
    Mesh m = box({0, 0, 0}, {L, W, h});
    Mesh up = box({0, 0, h}, {t, W, H});  // touches the base: coincident faces
    m.add(up);
    m.add(up);  // exported twice: duplicate faces
    double g = r.uni(12, 20), gy = r.uni(4, W * 0.4), gw = r.uni(5, 8);
    std::vector<Vector2d> prof = {{t, h}, {t + g, h}, {t, h + g}};  // gusset in xz
    Isometry3d T = Isometry3d::Identity();
    T.linear() = Matrix3d(Eigen::AngleAxisd(kPi / 2, Vector3d::UnitX()));
    T.translation() = Vector3d(0, gy + gw, 0);
    m.add(prism(prof, 0, gw), T);
    double bx = r.uni(t + 20, L - 12), by = r.uni(W * 0.55, W - 9);
    m.add(box({bx, by, h - 1}, {bx + 8, by + 8, h + r.uni(5, 9)}));  // a boss, sunk 1 mm into the base
    desc = "multi-body L-bracket (coincident and duplicate faces, gusset, boss)";
    return m;
}

// ---------------------------------------------------------------- files
void write_stl(const fs::path& p, const Mesh& m, double k) {
    std::ofstream o(p, std::ios::binary);
    char hdr[80] = {0};
    std::snprintf(hdr, sizeof hdr, "partloc_world2");
    o.write(hdr, 80);
    uint32_t n = uint32_t(m.f.size());
    o.write(reinterpret_cast<char*>(&n), 4);
    for (auto& t : m.f) {
        Vector3d a = m.v[t[0]] * k, b = m.v[t[1]] * k, c = m.v[t[2]] * k;
        Vector3d nn = (b - a).cross(c - a);
        if (nn.norm() > 0) nn.normalize();
        float buf[12] = {float(nn.x()), float(nn.y()), float(nn.z()), float(a.x()),
                         float(a.y()),  float(a.z()),  float(b.x()),  float(b.y()),
                         float(b.z()),  float(c.x()),  float(c.y()),  float(c.z())};
        o.write(reinterpret_cast<char*>(buf), sizeof buf);
        uint16_t attr = 0;
        o.write(reinterpret_cast<char*>(&attr), 2);
    }
}
void write_ply(const fs::path& p, const std::vector<Vector3d>& pts, double k) {
    std::ofstream o(p, std::ios::binary);
    o << "ply\nformat binary_little_endian 1.0\ncomment partloc_world2\nelement vertex " << pts.size()
      << "\nproperty float x\nproperty float y\nproperty float z\nend_header\n";
    for (auto& q : pts) {
        float b[3] = {float(q.x() * k), float(q.y() * k), float(q.z() * k)};
        o.write(reinterpret_cast<char*>(b), sizeof b);
    }
}
std::string num(double x) {
    if (std::abs(x) < 1e-12) x = 0;
    char b[64];
    std::snprintf(b, sizeof b, "%.12g", x);
    return b;
}
std::string matrix_yaml(const Isometry3d& T, double k) {
    std::string s = "{matrix: [";
    for (int i = 0; i < 4; ++i) {
        s += "[";
        for (int j = 0; j < 4; ++j) {
            double x = T.matrix()(i, j);
            if (j == 3 && i < 3) x *= k;
            s += num(x) + (j < 3 ? ", " : "");
        }
        s += i < 3 ? "], " : "]";
    }
    return s + "]}";
}
json matrix_json(const Isometry3d& T, double k) {
    json m = json::array();
    for (int i = 0; i < 4; ++i) {
        json row = json::array();
        for (int j = 0; j < 4; ++j) row.push_back(T.matrix()(i, j) * ((j == 3 && i < 3) ? k : 1.0));
        m.push_back(row);
    }
    return m;
}

// ---------------------------------------------------------------- the scene
struct Body {
    std::string name, kind;                 // kind: fiducial, workpiece, clutter, pallet, lookalike
    Mesh mesh;                              // in the body's own frame
    Isometry3d T = Isometry3d::Identity();  // machine <- body, axes at 0
    int fiducial = -1;
};

// ---------------------------------------------------------------- bodies must not interpenetrate
// Every body stands on the pallet, so two bodies meet wherever their footprints (convex hulls of their
// vertices seen from above) overlap. An earlier version placed fiducials 120-160 mm from the part without
// this check: in half the vise cells a fiducial stood partly inside the vise body, and partloc rightly found
// material where the model says there is air, even at the true pose.
std::vector<Vector2d> footprint(const Body& b) {
    std::vector<Vector2d> p;
    for (const auto& v : b.mesh.v) p.push_back((b.T * v).head<2>());
    std::sort(p.begin(), p.end(), [](const Vector2d& a, const Vector2d& c) {
        return a.x() < c.x() || (a.x() == c.x() && a.y() < c.y());
    });
    if (p.size() < 3) return p;
    std::vector<Vector2d> h(2 * p.size());  // Andrew's monotone chain, counter-clockwise
    std::size_t k = 0;
    const auto turn = [](const Vector2d& o, const Vector2d& a, const Vector2d& c) {
        return (a - o).x() * (c - o).y() - (a - o).y() * (c - o).x();
    };
    for (std::size_t i = 0; i < p.size(); ++i) {
        while (k >= 2 && turn(h[k - 2], h[k - 1], p[i]) <= 0) --k;
        h[k++] = p[i];
    }
    for (std::size_t i = p.size() - 1, t = k + 1; i > 0; --i) {
        while (k >= t && turn(h[k - 2], h[k - 1], p[i - 1]) <= 0) --k;
        h[k++] = p[i - 1];
    }
    h.resize(k - 1);
    return h;
}

/// Whether two convex footprints come closer than `gap` (separating axes: the edge normals of both).
bool footprints_meet(const std::vector<Vector2d>& a, const std::vector<Vector2d>& b, double gap) {
    for (const auto* poly : {&a, &b})
        for (std::size_t i = 0; i < poly->size(); ++i) {
            const Vector2d e = (*poly)[(i + 1) % poly->size()] - (*poly)[i];
            if (e.norm() < 1e-9) continue;
            const Vector2d n = Vector2d(e.y(), -e.x()).normalized();
            double a0 = 1e300, a1 = -1e300, b0 = 1e300, b1 = -1e300;
            for (const auto& q : a) a0 = std::min(a0, q.dot(n)), a1 = std::max(a1, q.dot(n));
            for (const auto& q : b) b0 = std::min(b0, q.dot(n)), b1 = std::max(b1, q.dot(n));
            if (a1 + gap <= b0 || b1 + gap <= a0) return false;
        }
    return true;
}

struct RayScene {
    RTCDevice dev;
    RTCScene sc;
    std::vector<int> geom_body;                  // geomID -> body index
    std::vector<std::vector<Vector3d>> normals;  // per geometry, per triangle (world)
    RayScene(const std::vector<Body>& bodies, const std::vector<int>& use) {
        dev = rtcNewDevice(nullptr);
        sc = rtcNewScene(dev);
        for (int bi : use) {
            const Body& b = bodies[size_t(bi)];
            Mesh w = b.mesh.transformed(b.T);
            RTCGeometry g = rtcNewGeometry(dev, RTC_GEOMETRY_TYPE_TRIANGLE);
            float* vb = static_cast<float*>(rtcSetNewGeometryBuffer(
                g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, 3 * sizeof(float), w.v.size()));
            for (size_t i = 0; i < w.v.size(); ++i)
                for (int c = 0; c < 3; ++c) vb[3 * i + size_t(c)] = float(w.v[i][c]);
            unsigned* ib = static_cast<unsigned*>(rtcSetNewGeometryBuffer(
                g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, 3 * sizeof(unsigned), w.f.size()));
            std::vector<Vector3d> nn;
            for (size_t i = 0; i < w.f.size(); ++i) {
                for (int c = 0; c < 3; ++c) ib[3 * i + size_t(c)] = unsigned(w.f[i][size_t(c)]);
                Vector3d n = (w.v[size_t(w.f[i][1])] - w.v[size_t(w.f[i][0])])
                                 .cross(w.v[size_t(w.f[i][2])] - w.v[size_t(w.f[i][0])]);
                nn.push_back(n.norm() > 0 ? n.normalized() : Vector3d(0, 0, 1));
            }
            rtcCommitGeometry(g);
            unsigned id = rtcAttachGeometry(sc, g);
            rtcReleaseGeometry(g);
            if (geom_body.size() <= id) geom_body.resize(id + 1, -1), normals.resize(id + 1);
            geom_body[id] = bi;
            normals[id] = nn;
        }
        rtcCommitScene(sc);
    }
    ~RayScene() {
        rtcReleaseScene(sc);
        rtcReleaseDevice(dev);
    }
    // first hit: distance, body, normal; false when nothing
    bool cast(const Vector3d& o, const Vector3d& d, double& t, int& body, Vector3d& n) const {
        RTCIntersectContext ctx;
        rtcInitIntersectContext(&ctx);
        RTCRayHit rh;
        rh.ray.org_x = float(o.x()), rh.ray.org_y = float(o.y()), rh.ray.org_z = float(o.z());
        rh.ray.dir_x = float(d.x()), rh.ray.dir_y = float(d.y()), rh.ray.dir_z = float(d.z());
        rh.ray.tnear = 0, rh.ray.tfar = 1e30f, rh.ray.mask = unsigned(-1), rh.ray.flags = 0, rh.ray.time = 0;
        rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
        rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
        rtcIntersect1(sc, &ctx, &rh);
        if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) return false;
        t = rh.ray.tfar;
        body = geom_body[rh.hit.geomID];
        n = normals[rh.hit.geomID][rh.hit.primID];
        return true;
    }
    bool occluded(const Vector3d& o, const Vector3d& d, double tfar) const {
        RTCIntersectContext ctx;
        rtcInitIntersectContext(&ctx);
        RTCRay r;
        r.org_x = float(o.x()), r.org_y = float(o.y()), r.org_z = float(o.z());
        r.dir_x = float(d.x()), r.dir_y = float(d.y()), r.dir_z = float(d.z());
        r.tnear = 0.02f, r.tfar = float(tfar), r.mask = unsigned(-1), r.flags = 0, r.time = 0;
        rtcOccluded1(sc, &ctx, &r);
        return r.tfar < 0;
    }
};

struct Sensor {  // one scan's scanner
    int W = 640, H = 480;
    double f = 1000;             // focal length, pixels
    double baseline = 120;       // camera to projector, mm, along the camera's x
    double noise = 0.1;          // 1-sigma along the ray, mm, at normal incidence
    double bias = 0.0;           // systematic offset along the ray, mm (positive: surfaces seen too far)
    double smooth = 0.0;         // 0..1: weight of the 3x3 neighbourhood mean
    int edge_px = 1;             // dropout within this many pixels of a depth jump
    double edge_p = 0.7;         // probability of dropping such a pixel
    double scale = 0.0;          // relative scale error about the point work_distance along the optical axis
    double outliers = 0.0;       // fraction of points thrown off the surface
    double max_incidence = 78;   // degrees
    double work_distance = 400;  // the scale error is about the point this far along the optical axis
                                 // (the centre of the calibrated volume); the scan frame is the camera's

    // The consumer depth camera (--sensor depthcam, render_depthcam): its errors are systematic and larger
    // than its local scatter, which is what real RealSense/Kinect-class scans of small parts show.
    bool depthcam = false;
    double bias_field = 0.0;  // mm: largest |low-frequency bias| over the image, added to `bias`
    struct Cosine {           // one term of the field: w cos(2 pi (fu u/W + fv v/H) + phase)
        double w = 0, fu = 0, fv = 0, phase = 0;
    };
    std::array<Cosine, 3> field{};  // normalised so that max |sum| over the image is 1
    int smooth_px = 7;              // pixels: side of the edge-blurring window (5, 7 or 9)
    double smooth_jump = 5.0;       // mm: the window mixes depths within this of the pixel's own
    double fly_p = 0.4;             // share of the pixels at a larger depth jump given a mixed depth
    double multipath = 1.0;         // mm: extra depth at an inside corner's crease
    double multipath_radius = 4.0;  // mm: how far from the crease the extra depth falls to zero
};

/// The depth camera's bias at pixel (u, v) (mm, positive: seen too far) and its gradient over the image
/// (mm per pixel).
double bias_at(const Sensor& s, double u, double v, Vector2d* grad = nullptr) {
    double b = s.bias;
    Vector2d g = Vector2d::Zero();
    for (const auto& c : s.field) {
        const double a = 2 * kPi * (c.fu * u / s.W + c.fv * v / s.H) + c.phase;
        b += s.bias_field * c.w * std::cos(a);
        g -= s.bias_field * c.w * std::sin(a) * 2 * kPi * Vector2d(c.fu / s.W, c.fv / s.H);
    }
    if (grad) *grad = g;
    return b;
}

struct ScanOut {
    std::vector<Vector3d> pts;  // scan frame, mm
    std::vector<int> body;      // per point: body index, -1 for an outlier (or a flying pixel)
    std::vector<int> pixel;     // per point: v * W + u (depthcam only: where its bias field is read)
    Isometry3d T_machine_scan;
    Isometry3d T_machine_cam;
    int shadowed = 0;  // camera hits the projector does not see
};

Isometry3d look_at(const Vector3d& eye, const Vector3d& target, Rng& r) {
    Vector3d z = (target - eye).normalized();
    Vector3d up = std::abs(z.z()) > 0.95 ? Vector3d(1, 0, 0) : Vector3d(0, 0, 1);
    Vector3d x = z.cross(up).normalized();
    // roll the camera about its axis by a random angle
    double roll = r.uni(-kPi, kPi);
    x = Eigen::AngleAxisd(roll, z) * x;
    Vector3d y = z.cross(x);
    Isometry3d T = Isometry3d::Identity();
    T.linear().col(0) = x, T.linear().col(1) = y, T.linear().col(2) = z;
    T.translation() = eye;
    return T;
}

// The camera's image: per pixel the ray, and where both the camera and the projector see a point its
// distance along the ray (-1 elsewhere). Draws no random number.
struct Image {
    std::vector<double> depth, inc;  // mm along the ray; |cos| of the incidence
    std::vector<int> body;
    std::vector<Vector3d> dirs;  // machine frame, unit
    std::vector<char> hit;       // the camera ray hits something, lit or not
    std::vector<Vector3d> X, N;  // the first hit and its normal (towards the camera), where hit
};
Image cast_image(const RayScene& rs, const Isometry3d& T_cam, const Sensor& s, ScanOut& out) {
    const Vector3d C = T_cam.translation();
    const Matrix3d R = T_cam.linear();
    const Vector3d P = C + R * Vector3d(s.baseline, 0.08 * s.baseline, 0);  // projector
    const size_t n = size_t(s.W * s.H);
    Image im;
    im.depth.assign(n, -1.0), im.inc.assign(n, 0.0), im.body.assign(n, -1), im.dirs.resize(n);
    im.hit.assign(n, 0), im.X.resize(n), im.N.resize(n);
    for (int v = 0; v < s.H; ++v)
        for (int u = 0; u < s.W; ++u) {
            size_t i = size_t(v * s.W + u);
            Vector3d d =
                R * Vector3d((u + 0.5 - s.W / 2.0) / s.f, (v + 0.5 - s.H / 2.0) / s.f, 1.0).normalized();
            im.dirs[i] = d;
            double t;
            int b;
            Vector3d nn;
            if (!rs.cast(C, d, t, b, nn)) continue;
            Vector3d X = C + t * d;
            im.hit[i] = 1, im.X[i] = X, im.N[i] = nn.dot(d) > 0 ? Vector3d(-nn) : nn;
            double cosc = std::abs(nn.dot(d));
            if (cosc < std::cos(deg(s.max_incidence))) continue;
            Vector3d toP = P - X;
            double dp = toP.norm();
            toP /= dp;
            // both rays on the same side of the face, and nothing between the point and the projector
            if ((nn.dot(-d) > 0) != (nn.dot(toP) > 0) || std::abs(nn.dot(toP)) < 0.1 ||
                rs.occluded(X, toP, dp - 0.05)) {
                ++out.shadowed;
                continue;
            }
            im.depth[i] = t;
            im.inc[i] = cosc;
            im.body[i] = b;
        }
    return im;
}

ScanOut render(const RayScene& rs, const Isometry3d& T_cam, const Sensor& s, Rng& r) {
    ScanOut out;
    out.T_machine_cam = T_cam;
    const Matrix3d R = T_cam.linear();
    const int n = s.W * s.H;
    Image im = cast_image(rs, T_cam, s, out);
    const std::vector<double>& depth = im.depth;
    const std::vector<double>& inc = im.inc;
    const std::vector<int>& body = im.body;
    const std::vector<Vector3d>& dirs = im.dirs;
    // noise and bias along the ray
    std::vector<double> meas(size_t(n), -1.0);
    for (int i = 0; i < n; ++i)
        if (depth[size_t(i)] > 0) {
            double sig = s.noise * (1.0 + 0.6 * (1.0 - inc[size_t(i)]));
            meas[size_t(i)] = depth[size_t(i)] + s.bias + sig * r.gauss();
        }
    // smoothing: a 3x3 mean over neighbours on the same surface patch (within 1 mm)
    std::vector<double> sm = meas;
    if (s.smooth > 0)
        for (int v = 1; v < s.H - 1; ++v)
            for (int u = 1; u < s.W - 1; ++u) {
                size_t i = size_t(v * s.W + u);
                if (meas[i] < 0) continue;
                double sum = 0;
                int c = 0;
                for (int dv = -1; dv <= 1; ++dv)
                    for (int du = -1; du <= 1; ++du) {
                        double m = meas[size_t((v + dv) * s.W + u + du)];
                        if (m > 0 && std::abs(m - meas[i]) < 1.0) sum += m, ++c;
                    }
                sm[i] = (1 - s.smooth) * meas[i] + s.smooth * sum / c;
            }
    // edge dropout: near a depth jump or a hole
    std::vector<char> keep(size_t(n), 0);
    for (int v = 0; v < s.H; ++v)
        for (int u = 0; u < s.W; ++u) {
            size_t i = size_t(v * s.W + u);
            if (sm[i] < 0) continue;
            keep[i] = 1;
            bool edge = false;
            for (int dv = -s.edge_px; dv <= s.edge_px && !edge; ++dv)
                for (int du = -s.edge_px; du <= s.edge_px && !edge; ++du) {
                    int uu = u + du, vv = v + dv;
                    if (uu < 0 || vv < 0 || uu >= s.W || vv >= s.H) continue;
                    double o = depth[size_t(vv * s.W + uu)];
                    if (o < 0 || std::abs(o - depth[i]) > 2.0) edge = true;
                }
            if (edge && r.chance(s.edge_p)) keep[i] = 0;
        }
    // the scan frame is the camera frame: origin at the optical centre, z along the view, x towards the
    // projector
    const Vector3d centre_cam(0, 0, s.work_distance);
    out.T_machine_scan = T_cam;
    for (int i = 0; i < n; ++i) {
        if (!keep[size_t(i)]) continue;
        double t = sm[size_t(i)];
        int b = body[size_t(i)];
        if (r.chance(s.outliers)) {
            t += r.chance(0.5) ? r.gauss() * 4.0 : r.uni(-30, 30);
            b = -1;
        }
        Vector3d pc = R.transpose() * (t * dirs[size_t(i)]);
        out.pts.push_back(centre_cam + (1.0 + s.scale) * (pc - centre_cam));
        out.body.push_back(b);
    }
    return out;
}

// The consumer depth camera (--sensor depthcam): the same camera and projector geometry (so the same
// shadowing), then, in this order, on the depth along each ray:
//  1. multipath: where the surface within multipath_radius of the pixel bends inwards (an inside corner),
//     light bounced off the other face arrives late and the depth reads farther, by up to `multipath` at
//     the crease, falling linearly to zero at multipath_radius. The rule: a neighbour in the window
//     (at most 8 pixels either way) is on another face (normals more than 30 deg apart), in front of the
//     pixel's face (more than 0.2 mm along its normal) and within 3 multipath_radius in space; the distance
//     is the pixel's to the crease, the line where the two faces' planes meet;
//  2. the bias field: `bias` (per scan) plus bias_field times the normalised cosine sum, read at the pixel;
//  3. edge blurring: each depth replaced, in share 0.7-1, by the mean of its smooth_px x smooth_px
//     window over the depths within smooth_jump of its own, across faces as well: convex edges are rounded;
//  4. flying pixels: a pixel next to a larger jump (more than smooth_jump, 4-neighbours) takes, with
//     probability fly_p, a depth between its own and its neighbour's, and belongs to no body;
//  5. noise along the ray after the filter (the scatter a user measures on the output, as in a datasheet);
//  6. the scale error about the work distance, as the present scanner.
// No edge dropout and no other outliers: the flying pixels are this sensor's outliers.
ScanOut render_depthcam(const RayScene& rs, const Isometry3d& T_cam, const Sensor& s, Rng& r) {
    ScanOut out;
    out.T_machine_cam = T_cam;
    out.T_machine_scan = T_cam;
    const Matrix3d R = T_cam.linear();
    const int W = s.W, H = s.H;
    const size_t n = size_t(W * H);
    Image im = cast_image(rs, T_cam, s, out);
    std::vector<double> d0(n, -1.0);  // after multipath and bias
    for (int v = 0; v < H; ++v)
        for (int u = 0; u < W; ++u) {
            const size_t i = size_t(v * W + u);
            if (im.depth[i] < 0) continue;
            const double pix_mm = im.depth[i] / s.f;
            const int w = std::min(8, int(std::ceil(s.multipath_radius / pix_mm)));
            double push = 0;
            for (int dv = -w; dv <= w; ++dv)
                for (int du = -w; du <= w; ++du) {
                    const int uu = u + du, vv = v + dv;
                    if (uu < 0 || vv < 0 || uu >= W || vv >= H) continue;
                    const size_t j = size_t(vv * W + uu);
                    if (!im.hit[j] || im.N[i].dot(im.N[j]) > std::cos(deg(30))) continue;
                    const Vector3d dX = im.X[j] - im.X[i];
                    // the crease: where the neighbour's plane meets the pixel's, at this distance from the
                    // pixel within its own plane (the hits on a face seen at a grazing angle lie too sparse
                    // to measure to them)
                    const double c = im.N[i].dot(im.N[j]);
                    const double dist = std::abs(im.N[j].dot(dX)) / std::sqrt(1.0 - c * c);
                    if (im.N[i].dot(dX) > 0.2 && dX.norm() < 3 * s.multipath_radius &&
                        dist < s.multipath_radius)
                        push = std::max(push, s.multipath * (1.0 - dist / s.multipath_radius));
                }
            d0[i] = im.depth[i] + push + bias_at(s, u + 0.5, v + 0.5);
        }
    std::vector<double> d1 = d0;  // edge-blurred
    const int hw = s.smooth_px / 2;
    const double mix = s.smooth;
    for (int v = 0; v < H; ++v)
        for (int u = 0; u < W; ++u) {
            const size_t i = size_t(v * W + u);
            if (d0[i] < 0) continue;
            double sum = 0;
            int c = 0;
            for (int dv = -hw; dv <= hw; ++dv)
                for (int du = -hw; du <= hw; ++du) {
                    const int uu = u + du, vv = v + dv;
                    if (uu < 0 || vv < 0 || uu >= W || vv >= H) continue;
                    const double m = d0[size_t(vv * W + uu)];
                    if (m > 0 && std::abs(m - d0[i]) < s.smooth_jump) sum += m, ++c;
                }
            d1[i] = (1 - mix) * d0[i] + mix * sum / c;
        }
    const Vector3d centre_cam(0, 0, s.work_distance);
    for (int v = 0; v < H; ++v)
        for (int u = 0; u < W; ++u) {
            const size_t i = size_t(v * W + u);
            if (d1[i] < 0) continue;
            double t = d1[i];
            int b = im.body[i];
            double jump = 0;  // the largest jump to a 4-neighbour, signed towards it
            const int nb[4][2] = {{1, 0}, {-1, 0}, {0, 1}, {0, -1}};
            for (const auto& o : nb) {
                const int uu = u + o[0], vv = v + o[1];
                if (uu < 0 || vv < 0 || uu >= W || vv >= H) continue;
                const double m = d1[size_t(vv * W + uu)];
                if (m > 0 && std::abs(m - t) > std::abs(jump)) jump = m - t;
            }
            if (std::abs(jump) > s.smooth_jump && r.chance(s.fly_p)) t += r.uni(0.15, 0.85) * jump, b = -1;
            t += s.noise * (1.0 + 0.6 * (1.0 - im.inc[i])) * r.gauss();
            const Vector3d pc = R.transpose() * (t * im.dirs[i]);
            out.pts.push_back(centre_cam + (1.0 + s.scale) * (pc - centre_cam));
            out.body.push_back(b);
            out.pixel.push_back(int(i));
        }
    return out;
}

// point to triangle distance (for the self-test)
double tri_dist(const Vector3d& p, const Vector3d& a, const Vector3d& b, const Vector3d& c) {
    Vector3d ab = b - a, ac = c - a, ap = p - a;
    double d1 = ab.dot(ap), d2 = ac.dot(ap);
    if (d1 <= 0 && d2 <= 0) return (p - a).norm();
    Vector3d bp = p - b;
    double d3 = ab.dot(bp), d4 = ac.dot(bp);
    if (d3 >= 0 && d4 <= d3) return (p - b).norm();
    double vc = d1 * d4 - d3 * d2;
    if (vc <= 0 && d1 >= 0 && d3 <= 0) return (p - (a + ab * (d1 / (d1 - d3)))).norm();
    Vector3d cp = p - c;
    double d5 = ab.dot(cp), d6 = ac.dot(cp);
    if (d6 >= 0 && d5 <= d6) return (p - c).norm();
    double vb = d5 * d2 - d1 * d6;
    if (vb <= 0 && d2 >= 0 && d6 <= 0) return (p - (a + ac * (d2 / (d2 - d6)))).norm();
    double va = d3 * d6 - d5 * d4;
    if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0)
        return (p - (b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6))))).norm();
    double den = 1.0 / (va + vb + vc);
    return (p - (a + ab * (vb * den) + ac * (vc * den))).norm();
}
double mesh_dist(const Vector3d& p, const Mesh& m) {
    double best = 1e30;
    for (auto& t : m.f)
        best = std::min(best, tri_dist(p, m.v[size_t(t[0])], m.v[size_t(t[1])], m.v[size_t(t[2])]));
    return best;
}

/// Where a depth camera's systematic errors put a right rigid fit: a point-to-plane fit (Gauss-Newton,
/// points farther than 3 mm from their surface left out) of the scan's fiducial points (at most 3000) to
/// their own fiducial's model, started at the truth. `meshes` are the fiducials in the machine frame as the
/// scan saw them (body index -> mesh; empty for other bodies).
Isometry3d reference_fit(const std::vector<Vector3d>& pts, const std::vector<int>& body,
                         const std::vector<Mesh>& meshes, Isometry3d T) {
    std::vector<size_t> idx;
    for (size_t p = 0; p < pts.size(); ++p)
        if (body[p] >= 0 && !meshes[size_t(body[p])].f.empty()) idx.push_back(p);
    const size_t step = std::max<size_t>(1, idx.size() / 3000);
    for (int it = 0; it < 15; ++it) {
        Eigen::Matrix<double, 6, 6> H = Eigen::Matrix<double, 6, 6>::Zero();
        Eigen::Matrix<double, 6, 1> g = Eigen::Matrix<double, 6, 1>::Zero();
        for (size_t q = 0; q < idx.size(); q += step) {
            const Vector3d x = T * pts[idx[q]];
            const Mesh& m = meshes[size_t(body[idx[q]])];
            double best = 1e30;
            size_t bt = 0;
            for (size_t t = 0; t < m.f.size(); ++t) {
                const double d =
                    tri_dist(x, m.v[size_t(m.f[t][0])], m.v[size_t(m.f[t][1])], m.v[size_t(m.f[t][2])]);
                if (d < best) best = d, bt = t;
            }
            const Vector3d a = m.v[size_t(m.f[bt][0])];
            Vector3d n = (m.v[size_t(m.f[bt][1])] - a).cross(m.v[size_t(m.f[bt][2])] - a);
            if (best > 3.0 || n.norm() == 0) continue;
            n.normalize();
            const double r = n.dot(x - a);
            Eigen::Matrix<double, 6, 1> J;
            J << x.cross(n), n;
            H += J * J.transpose(), g += J * r;
        }
        H += 1e-9 * H.trace() * Eigen::Matrix<double, 6, 6>::Identity();
        const Eigen::Matrix<double, 6, 1> d = -H.ldlt().solve(g);
        Isometry3d D = Isometry3d::Identity();
        const Vector3d w = d.head<3>();
        if (w.norm() > 0) D.linear() = Eigen::AngleAxisd(w.norm(), w.normalized()).toRotationMatrix();
        D.translation() = d.tail<3>();
        T = D * T;
        if (d.norm() < 1e-7) break;
    }
    return T;
}

// ---------------------------------------------------------------- the cell
struct Scan {
    ScanOut out;
    Sensor sensor;
    std::string trap;  // "", "no_fiducial", "plane", "mirror"
    double A = 0;      // rotary axis value, degrees
    std::vector<int> fid_counts;
};
struct Cell {
    std::vector<Body> bodies;
    std::vector<Scan> scans;
    std::vector<std::string> fid_desc;
    Isometry3d T_nominal_wp, T_true_wp;
    Mesh wp_nominal;              // workpiece frame
    std::vector<Mesh> wp_datums;  // workpiece frame: the three finished faces
    bool rotary = false, scanner_block = true, use_datums = false;
    double spacing = 0.4, noise = 0.1;
    std::string layout;
};

Isometry3d rot_A(double a_deg) {  // rotary axis A about machine X through the origin
    Isometry3d M = Isometry3d::Identity();
    M.linear() = Matrix3d(Eigen::AngleAxisd(deg(a_deg), Vector3d::UnitX()));
    return M;
}

Mesh rect(Vector3d o, Vector3d e1, Vector3d e2) {  // a rectangle facing e1 x e2
    Mesh m;
    m.v = {o, o + e1, o + e1 + e2, o + e2};
    m.f = {{0, 1, 2}, {0, 2, 3}};
    return m;
}

bool g_ideal =
    false;  // --ideal: a perfect sensor (no noise, bias, smoothing, dropout, scale error, outliers)
bool g_no_scale = false;  // --no-scale: the sensor as drawn, but without its scale error
bool g_depthcam =
    false;  // --sensor depthcam: a consumer depth camera instead of the structured-light scanner
bool g_no_noise = false;  // self-test only: the sensor as drawn, without its random noise

Cell build_cell(uint64_t seed, bool small) {
    Rng r(seed);
    Cell c;
    c.rotary = r.chance(0.3);
    c.scanner_block = r.chance(0.7);
    c.use_datums = r.chance(0.5);
    // pallet: top at z = 0
    c.bodies.push_back(
        {"pallet", "pallet", box({-260, -200, -25}, {260, 200, 0}), Isometry3d::Identity(), -1});
    // workpiece: nominal part = a block with a boss; the datum corner faces (x = 0, y = 0 walls and the top)
    // are finished, the rest carries 0.3-1.0 mm of extra stock
    double Lx = r.uni(80, 130), Ly = r.uni(50, 80), Lz = r.uni(30, 50);
    double bx0 = r.uni(0.45, 0.6) * Lx, bx1 = bx0 + r.uni(15, 0.35 * Lx), by0 = r.uni(0.2, 0.4) * Ly,
           by1 = by0 + r.uni(12, 0.4 * Ly), bh = r.uni(8, 15);
    c.wp_nominal = box({0, 0, 0}, {Lx, Ly, Lz});
    c.wp_nominal.add(box({bx0, by0, Lz}, {bx1, by1, Lz + bh}));
    double sx = r.uni(0.3, 1.0), sy = r.uni(0.3, 1.0), sb = r.uni(0.3, 1.0);
    Mesh stock = box({0, 0, 0}, {Lx + sx, Ly + sy, Lz});
    stock.add(box({bx0 - sb, by0 - sb, Lz - 1}, {bx1 + sb, by1 + sb, Lz + bh + sb}));
    c.wp_datums = {rect({0, 0, Lz}, {Lx, 0, 0}, {0, Ly, 0}),  // top (primary)
                   rect({0, 0, 0}, {0, 0, Lz}, {0, Ly, 0}),   // x = 0 wall, facing -x
                   rect({0, 0, 0}, {Lx, 0, 0}, {0, 0, Lz})};  // y = 0 wall, facing -y
    bool vise = r.chance(0.5);
    double zbase = vise ? r.uni(40, 60) : 0.0;
    double yaw = r.uni(-180, 180);
    c.T_nominal_wp = pose(Vector3d(r.uni(-20, 20) - Lx / 2, r.uni(-15, 15) - Ly / 2, zbase), 0, 0, 0);
    // yaw about the part's centre
    {
        Isometry3d Tc = pose(Vector3d(Lx / 2, Ly / 2, 0), 0, 0, 0);
        c.T_nominal_wp =
            pose(c.T_nominal_wp.translation() + Vector3d(Lx / 2, Ly / 2, 0), 0, 0, yaw) * Tc.inverse();
    }
    Isometry3d dT = pose(Vector3d(r.uni(-2, 2), r.uni(-2, 2), r.uni(-0.5, 0.5)), r.uni(-0.4, 0.4),
                         r.uni(-0.4, 0.4), r.uni(-2, 2));
    c.T_true_wp = c.T_nominal_wp * dT;
    c.bodies.push_back({"workpiece", "workpiece", stock, c.T_true_wp, -1});
    if (vise) {
        c.layout = "vise";
        double jt = r.uni(18, 25), jh = r.uni(0.35, 0.6) * Lz, ext = r.uni(15, 30);
        Mesh v =
            box({-ext, -jt - 40, -zbase}, {Lx + ext, Ly + sy + jt + 40, -10});  // vise body below the part
        v.add(box({-ext * 0.5, -jt, -10}, {Lx + ext * 0.5, 0, jh}));            // fixed jaw
        v.add(box({-ext * 0.5, Ly + sy, -10}, {Lx + ext * 0.5, Ly + sy + jt, jh}));  // moving jaw
        v.add(box({Lx * 0.1, -5, -10}, {Lx * 0.9, Ly + sy + 5, 0}));                 // parallels
        c.bodies.push_back({"vise", "clutter", v, c.T_true_wp, -1});
    } else {
        c.layout = "clamps";
        for (int k = 0; k < 2; ++k) {  // strap clamps on the x = Lx end and the y = Ly side
            Mesh m = box({0, 0, 0}, {60, 18, 12});
            m.add(box({38, 2, -Lz}, {52, 16, 0}));  // heel block down to the pallet
            m.add(box({22, 5, 12}, {34, 13, 28}));  // stud and nut
            Isometry3d T = k == 0 ? pose(Vector3d(Lx - 15, Ly * 0.3, Lz), 0, 0, 0)
                                  : pose(Vector3d(Lx * 0.3, Ly - 15, Lz), 0, 0, 90);
            c.bodies.push_back({"clamp" + std::to_string(k), "clutter", m, c.T_true_wp * T, -1});
        }
    }
    // fiducials around the part, in sectors; the other sectors get a second part, a fixture, a look-alike
    int nf = r.integer(2, 3);
    std::vector<int> fam = {0, 1, 2, 3};
    std::shuffle(fam.begin(), fam.end(), r.g);
    int nsect = 6;
    std::vector<int> sect = {0, 1, 2, 3, 4, 5};
    std::shuffle(sect.begin(), sect.end(), r.g);
    // fiducial A stands off the part's datum corner (where its finished x = 0 and y = 0 walls face), as a
    // machinist sets a cell up so that one scan sees the datum faces and a fiducial together
    double corner_az = yaw + 225.0;
    double a0 = corner_az - 360.0 / nsect * sect[0];
    Vector3d centre = c.T_nominal_wp * Vector3d(Lx / 2, Ly / 2, 0);
    centre.z() = 0;
    auto place = [&](int s, double rad) {
        double a = deg(a0 + 360.0 / nsect * s + r.uni(-12, 12));
        return Vector3d(centre.x() + rad * std::cos(a), centre.y() + rad * std::sin(a), 0);
    };
    // A body goes in its sector at a radius drawn from [r0, r1], pushed out 5 mm and drawn again (angle
    // and turn too) while its footprint comes within 5 mm of a body already there or leaves the pallet.
    auto place_body = [&](Body b, int s, double r0, double r1, const Isometry3d& offset) {
        constexpr int kTries = 40;
        for (int t = 0; t < kTries; ++t) {
            const Vector3d p = place(s, r.uni(r0, r1) + 5.0 * t);
            b.T = pose(p, 0, 0, r.uni(-180, 180)) * offset;
            const auto fb = footprint(b);
            bool free = std::all_of(fb.begin(), fb.end(), [](const Vector2d& q) {
                return std::abs(q.x()) < 255.0 && std::abs(q.y()) < 195.0;
            });
            for (std::size_t o = 0; free && o < c.bodies.size(); ++o)
                free = c.bodies[o].kind == "pallet" || !footprints_meet(fb, footprint(c.bodies[o]), 5.0);
            if (free) break;
            if (t + 1 == kTries)
                std::fprintf(stderr, "world2: %s placed where it meets another body\n", b.name.c_str());
        }
        c.bodies.push_back(std::move(b));
    };
    for (int k = 0; k < nf; ++k) {
        std::string d;
        Mesh m = fam[size_t(k)] == 0   ? fid_stepped(r, d)
                 : fam[size_t(k)] == 1 ? fid_notched(r, d)
                 : fam[size_t(k)] == 2 ? fid_pyramid(r, d)
                                       : fid_multibody(r, d);
        place_body({std::string(1, char('A' + k)), "fiducial", m, Isometry3d::Identity(), k}, sect[size_t(k)],
                   120, 160, pose(Vector3d(-25, -20, 0), 0, 0, 0));
        c.fid_desc.push_back(d);
    }
    int next = nf;
    {  // a second part: a plate with a pocket-like step
        std::vector<Vector2d> poly = {{0, 0}, {70, 0}, {70, 25}, {45, 25}, {45, 50}, {0, 50}};
        Mesh m = prism(poly, 0, r.uni(15, 30));
        place_body({"second_part", "clutter", m, Isometry3d::Identity(), -1}, sect[size_t(next++)], 130, 170,
                   pose(Vector3d(-35, -25, 0), 0, 0, 0));
    }
    if (next < nsect) {  // an angle plate fixture
        Mesh m = box({0, 0, 0}, {60, 60, 12});
        m.add(box({0, 0, 0}, {12, 60, r.uni(50, 80)}));
        place_body({"angle_plate", "clutter", m, Isometry3d::Identity(), -1}, sect[size_t(next++)], 140, 175,
                   pose(Vector3d(-30, -30, 0), 0, 0, 0));
    }
    bool mirror_trap = r.chance(0.5) && next < nsect;
    if (mirror_trap) {  // a mirrored copy of fiducial A: same faces, the other hand
        const Body& A = c.bodies[2 + (vise ? 1 : 2)];
        Mesh m = A.mesh.mirrored_x();
        place_body({"mirror_of_A", "lookalike", m, Isometry3d::Identity(), -1}, sect[size_t(next++)], 140,
                   170, Isometry3d::Identity());
    }
    // ---- scans
    // the depth camera: 640 x 480 at 350-600 mm gives 0.6-1.0 mm between points (the same two draws, so
    // the bodies and the stream up to the first scan are the same as the scanner's)
    c.spacing = g_depthcam ? r.uni(0.6, 1.0) : r.uni(0.3, 0.5);
    c.noise = g_depthcam ? r.uni(0.2, 0.35) : r.uni(0.04, 0.18);
    std::vector<int> all;
    for (size_t i = 0; i < c.bodies.size(); ++i) all.push_back(int(i));
    RayScene rs(c.bodies, all);
    std::vector<int> fid_bodies, look_bodies;
    for (size_t i = 0; i < c.bodies.size(); ++i) {
        if (c.bodies[i].kind == "fiducial") fid_bodies.push_back(int(i));
        if (c.bodies[i].kind == "lookalike") look_bodies.push_back(int(i));
    }
    auto body_centre = [&](int b) {
        Vector3d s = Vector3d::Zero();
        for (auto& v : c.bodies[size_t(b)].mesh.v) s += v;
        return Vector3d(c.bodies[size_t(b)].T * (s / double(c.bodies[size_t(b)].mesh.v.size())));
    };
    Vector3d wp_c = c.T_true_wp * Vector3d(Lx / 2, Ly / 2, Lz / 2);
    auto make_sensor = [&](double dist) {
        Sensor s;
        if (small) s.W = 320, s.H = 240;
        s.work_distance = dist;
        s.f = dist / (c.spacing * r.uni(0.9, 1.1)) * (small ? 0.5 : 1.0);
        s.baseline = r.uni(80, 160);
        s.noise = c.noise * r.uni(0.8, 1.2);
        s.bias = r.uni(-0.15, 0.3);
        s.smooth = r.uni(0.0, 0.6);
        s.edge_px = r.integer(1, 2);
        s.edge_p = r.uni(0.4, 1.0);
        s.scale = r.uni(-0.0012, 0.0012);
        s.outliers = r.chance(0.3) ? r.uni(0.002, 0.02) : 0.0;
        if (g_no_scale) s.scale = 0;
        if (g_ideal) s.noise = 0.01, s.bias = 0, s.smooth = 0, s.edge_p = 0, s.scale = 0, s.outliers = 0;
        return s;
    };
    auto make_depthcam = [&](double dist) {
        Sensor s;
        s.depthcam = true;
        if (small) s.W = 320, s.H = 240;
        s.work_distance = dist;
        s.f = dist / (c.spacing * r.uni(0.9, 1.1)) * (small ? 0.5 : 1.0);
        s.baseline = r.uni(50, 95);  // RealSense D4xx 50-55 mm, Kinect v1 75 mm
        s.noise = c.noise;           // the datasheet's figure, as the job's scanner block gives it
        s.bias = (r.chance(0.5) ? -1.0 : 1.0) * r.uni(0.3, 1.5);
        s.bias_field = r.uni(0.3, 1.0);
        for (auto& t : s.field)  // up to about one cycle over the image: a smooth, low-order field
            t = {r.uni(0.5, 1.0), r.uni(-1.0, 1.0), r.uni(-1.0, 1.0), r.uni(0, 2 * kPi)};
        {  // normalise: the largest |sum| over the image (on a 32 x 24 grid) is 1
            Sensor unit = s;
            unit.bias = 0, unit.bias_field = 1;
            double m = 1e-9;
            for (int v = 0; v <= 24; ++v)
                for (int u = 0; u <= 32; ++u)
                    m = std::max(m, std::abs(bias_at(unit, u * s.W / 32.0, v * s.H / 24.0)));
            for (auto& t : s.field) t.w /= m;
        }
        s.smooth_px = 5 + 2 * r.integer(0, 2);
        s.smooth = r.uni(0.7, 1.0);
        s.smooth_jump = r.uni(3.0, 8.0);
        s.fly_p = r.uni(0.2, 0.6);
        s.multipath = r.uni(0.5, 1.5);
        s.multipath_radius = r.uni(3.0, 5.0);
        s.scale = r.uni(-0.003, 0.003);
        s.edge_p = 0, s.outliers = 0;
        if (g_no_scale) s.scale = 0;
        if (g_no_noise) s.noise = 0, s.fly_p = 0;
        if (g_ideal) s = make_sensor(dist);  // the scanner's perfect sensor (make_sensor applies --ideal)
        return s;
    };
    auto sensor_for = [&](double dist) { return g_depthcam ? make_depthcam(dist) : make_sensor(dist); };
    auto scan_with = [&](const Isometry3d& Tc, const Sensor& s) {
        return s.depthcam ? render_depthcam(rs, Tc, s, r) : render(rs, Tc, s, r);
    };
    auto counts = [&](const ScanOut& o) {
        std::vector<int> n(size_t(nf), 0);
        for (int b : o.body)
            if (b >= 0 && c.bodies[size_t(b)].fiducial >= 0) ++n[size_t(c.bodies[size_t(b)].fiducial)];
        return n;
    };
    int nscans = small ? 3 : r.integer(5, 7);
    std::vector<double> A_values = {0, 30, -30, 60, -45, 15, 45};
    for (int k = 0; k < nscans; ++k) {
        Scan s;
        double dist = g_depthcam ? r.uni(350, 600) : r.uni(300, 480);
        s.sensor = sensor_for(dist);
        Vector3d fc = body_centre(fid_bodies[size_t(k % nf)]);
        Vector3d target = wp_c + r.uni(0.3, 0.65) * (fc - wp_c);
        // the scanner stands on the fiducial's side of the part, looking in and down
        double az = std::atan2(fc.y() - wp_c.y(), fc.x() - wp_c.x()) + deg(r.uni(-60, 60)),
               el = deg(r.uni(35, 70));
        Vector3d dir(std::cos(el) * std::cos(az), std::cos(el) * std::sin(az), std::sin(el));
        Isometry3d Tc = look_at(target + dist * dir, target, r);
        s.out = scan_with(Tc, s.sensor);
        s.fid_counts = counts(s.out);
        if (c.rotary) {
            s.A = A_values[size_t(k) % A_values.size()];
            // the pallet frame is the machine frame at A = 0; at A the scanner (fixed in the machine) sees
            // the pallet turned: machine <- scan = M(A) * pallet <- scan
            s.out.T_machine_scan = rot_A(s.A) * s.out.T_machine_scan;
        }
        c.scans.push_back(std::move(s));
    }
    // traps
    auto trap = [&](const std::string& kind, Vector3d target, int tries) {
        for (int t = 0; t < tries; ++t) {
            Scan s;
            double dist = r.uni(260, 340);
            s.sensor = sensor_for(dist);
            // a close view: the scanner's smaller frame; the depth camera's scan cropped as a user would
            s.sensor.W = small ? 200 : 400, s.sensor.H = small ? 150 : 300;
            if (s.sensor.depthcam) s.sensor.W = small ? 160 : 240, s.sensor.H = small ? 120 : 180;
            double az = r.uni(0, 2 * kPi), el = deg(r.uni(50, 85));
            Vector3d dir(std::cos(el) * std::cos(az), std::cos(el) * std::sin(az), std::sin(el));
            Vector3d tg = target + Vector3d(r.uni(-10, 10), r.uni(-10, 10), 0);
            s.out = scan_with(look_at(tg + dist * dir, tg, r), s.sensor);
            s.fid_counts = counts(s.out);
            int nfid = 0, other = 0;
            for (int n : s.fid_counts) nfid += n;
            for (int b : s.out.body)
                if (b > 0) ++other;
            if (nfid > 0 || s.out.pts.size() < 5000) continue;
            if (kind == "plane" && other > 0) continue;
            s.trap = kind;
            if (c.rotary) {
                s.A = A_values[size_t(c.scans.size()) % A_values.size()];
                s.out.T_machine_scan = rot_A(s.A) * s.out.T_machine_scan;
            }
            c.scans.push_back(std::move(s));
            return;
        }
    };
    if (!small || true) {
        if (r.chance(0.6)) trap("no_fiducial", wp_c, 30);
        if (r.chance(0.5)) {  // a bare patch of pallet: a corner
            Vector3d corner(r.chance(0.5) ? 225 : -225, r.chance(0.5) ? 165 : -165, 0);
            trap("plane", corner, 30);
        }
        if (mirror_trap) trap("mirror", body_centre(look_bodies[0]), 30);
    }
    // shuffle so that traps are not always last
    std::shuffle(c.scans.begin(), c.scans.end(), r.g);
    return c;
}

double unit_factor(const std::string& u) {  // job units per mm
    if (u == "mm") return 1.0;
    if (u == "um") return 1000.0;
    if (u == "m") return 0.001;
    if (u == "in") return 1.0 / 25.4;
    throw std::runtime_error("unknown unit " + u + " (um, mm, m, in)");
}

void write_cell(const Cell& c, const fs::path& dir, uint64_t seed, const std::string& unit) {
    const double k = unit_factor(unit);
    fs::create_directories(dir / "models");
    fs::create_directories(dir / "scans");
    std::ostringstream y;
    y << "# partloc_world2 seed " << seed << " (" << c.layout << (c.rotary ? ", rotary A" : "") << ")\n";
    y << "units: " << unit << "\n";
    if (c.scanner_block)
        y << "scanner:\n  point_spacing: " << num(c.spacing * k) << "\n  noise: " << num(c.noise * k) << "\n";
    if (c.rotary)
        y << "machine:\n  axes:\n    - {name: A, type: rotary, direction: [1, 0, 0], point: [0, 0, 0]}\n";
    std::string mw = c.rotary ? "[A]" : "[]";
    y << "fiducials:\n";
    json truth;
    truth["seed"] = seed;
    truth["units"] = unit;
    truth["layout"] = c.layout;
    truth["rotary"] = c.rotary;
    truth["fiducials"] = json::array();
    for (auto& b : c.bodies)
        if (b.kind == "fiducial") {
            std::string f = "models/fiducial_" + b.name + ".stl";
            write_stl(dir / f, b.mesh, k);
            y << "  - name: " << b.name << "\n    model: " << f << "\n    pose: " << matrix_yaml(b.T, k)
              << "\n    moves_with: " << mw << "\n";
            truth["fiducials"].push_back({{"name", b.name},
                                          {"design", c.fid_desc[size_t(b.fiducial)]},
                                          {"T_machine_fiducial", matrix_json(b.T, k)}});
        }
    // workpiece: reference surfaces (or datums) and the final part, at the nominal pose, machine frame
    Mesh ref;
    for (auto& d : c.wp_datums) ref.add(d, c.T_nominal_wp);
    write_stl(dir / "models/final_part.stl", c.wp_nominal.transformed(c.T_nominal_wp), k);
    y << "workpiece:\n";
    if (c.use_datums) {
        const char* names[3] = {"A", "B", "C"};
        y << "  datums:\n";
        for (int i = 0; i < 3; ++i) {
            std::string f = std::string("models/datum_") + names[i] + ".stl";
            write_stl(dir / f, c.wp_datums[size_t(i)].transformed(c.T_nominal_wp), k);
            y << "    - {name: " << names[i] << ", surfaces: " << f << "}\n";
        }
    } else {
        write_stl(dir / "models/workpiece_reference.stl", ref, k);
        y << "  reference_surfaces: models/workpiece_reference.stl\n";
    }
    y << "  datum: " << matrix_yaml(c.T_nominal_wp, k)
      << "\n  final_part: models/final_part.stl\n  moves_with: " << mw << "\nscans:\n";
    truth["T_machine_workpiece"] = matrix_json(c.T_true_wp, k);
    truth["T_machine_workpiece_nominal"] = matrix_json(c.T_nominal_wp, k);
    {  // the part's extent (workpiece frame) for the error at its corners
        Eigen::AlignedBox3d bb;
        for (auto& v : c.wp_nominal.v) bb.extend(v);
        truth["workpiece_box"] = {{bb.min().x() * k, bb.min().y() * k, bb.min().z() * k},
                                  {bb.max().x() * k, bb.max().y() * k, bb.max().z() * k}};
    }
    truth["scans"] = json::array();
    for (size_t i = 0; i < c.scans.size(); ++i) {
        const Scan& s = c.scans[i];
        char name[64];
        std::snprintf(name, sizeof name, "scans/scan_%02zu.ply", i + 1);
        write_ply(dir / name, s.out.pts, k);
        y << "  - {file: " << name;
        if (c.rotary) y << ", axes: {A: " << num(s.A) << "}";
        y << "}\n";
        json js;
        js["file"] = name;
        js["trap"] = s.trap.empty() ? json(nullptr) : json(s.trap);
        js["T_machine_scan"] = matrix_json(s.out.T_machine_scan, k);
        js["A"] = s.A;
        js["points"] = s.out.pts.size();
        js["shadowed"] = s.out.shadowed;
        json fc = json::object();
        int total = 0;
        for (size_t f = 0; f < s.fid_counts.size(); ++f)
            fc[std::string(1, char('A' + f))] = s.fid_counts[f], total += s.fid_counts[f];
        js["fiducial_points"] = fc;
        js["fiducial_points_total"] = total;
        // check points: up to 60 of the scan's fiducial points (else any points), scan frame
        std::vector<size_t> idx;
        for (size_t p = 0; p < s.out.pts.size(); ++p)
            if (s.out.body[p] >= 0 && c.bodies[size_t(s.out.body[p])].fiducial >= 0) idx.push_back(p);
        if (idx.empty())
            for (size_t p = 0; p < s.out.pts.size(); ++p) idx.push_back(p);
        json cp = json::array();
        std::vector<Vector3d> cpts;
        double rmax = 0;
        for (size_t q = 0; q < 60 && !idx.empty(); ++q) {
            const Vector3d& p = s.out.pts[idx[q * idx.size() / 60]];
            cp.push_back({p.x() * k, p.y() * k, p.z() * k});
            cpts.push_back(p);
            rmax = std::max(rmax, (p - Vector3d(0, 0, s.sensor.work_distance)).norm());
        }
        js["check_points"] = cp;
        js["sensor"] = {{"noise", s.sensor.noise * k},
                        {"bias", s.sensor.bias * k},
                        {"scale_error", s.sensor.scale},
                        {"smoothing", s.sensor.smooth},
                        {"edge_dropout_px", s.sensor.edge_px},
                        {"edge_dropout_p", s.sensor.edge_p},
                        {"outliers", s.sensor.outliers},
                        {"baseline", s.sensor.baseline * k},
                        {"distance", s.sensor.work_distance * k},
                        {"focal_px", s.sensor.f}};
        // tolerance on the check points: 0.1 mm, plus what the sensor's own systematic errors move a right
        // rigid fit by (the bias along the line of sight; the scale error at the check points' distance from
        // the centre of the scanner's volume, work_distance along its axis, about which it scales)
        double bias_tol = std::abs(s.sensor.bias), rot_tol = 0.05;
        if (s.sensor.depthcam) {
            // the depth camera's bias varies over the image: a right rigid fit is moved by about the largest
            // |bias| over the fiducials' pixels, and turned by about the field's steepest slope over them
            // (mm of bias per mm across the surface: per pixel over the pixel's footprint, depth / f)
            double bmax = 0, slope = 0;
            for (size_t p = 0; p < s.out.pts.size(); ++p) {
                if (s.out.body[p] < 0 || c.bodies[size_t(s.out.body[p])].fiducial < 0) continue;
                const int pix = s.out.pixel[p];
                Vector2d g;
                bmax = std::max(
                    bmax, std::abs(bias_at(s.sensor, pix % s.sensor.W + 0.5, pix / s.sensor.W + 0.5, &g)));
                slope = std::max(slope, g.norm() * s.sensor.f / s.out.pts[p].norm());
            }
            // and where a right rigid fit lands: the reference fit's error at the check points and its turn
            double fit_err = 0, fit_rot = 0;
            if (bmax > 0) {
                std::vector<Mesh> meshes(c.bodies.size());
                for (size_t b = 0; b < c.bodies.size(); ++b)
                    if (c.bodies[b].fiducial >= 0)
                        meshes[b] = c.bodies[b].mesh.transformed(rot_A(s.A) * c.bodies[b].T);
                const Isometry3d Tf = reference_fit(s.out.pts, s.out.body, meshes, s.out.T_machine_scan);
                for (const auto& p : cpts)
                    fit_err = std::max(fit_err, (Tf * p - s.out.T_machine_scan * p).norm());
                fit_rot = Eigen::AngleAxisd(Tf.linear() * s.out.T_machine_scan.linear().transpose()).angle() *
                          180.0 / kPi;
                js["T_machine_scan_reference_fit"] = matrix_json(Tf, k);
            }
            js["sensor"]["reference_fit_error"] = fit_err * k;
            js["sensor"]["reference_fit_rotation_deg"] = fit_rot;
            // the larger of the two: the bias bounds a fit's shift at a point, but two fiducials biased apart
            // turn the fit by more than the field's slope (seeds 1-40: up to 0.76 deg, median 0.19)
            bias_tol = std::max(bmax, fit_err);
            rot_tol = 0.05 + std::max(std::atan(slope) * 180.0 / kPi, fit_rot);
            js["sensor"]["model"] = "depthcam";
            js["sensor"]["bias_field"] = s.sensor.bias_field * k;
            js["sensor"]["bias_max_on_fiducials"] = bmax * k;
            js["sensor"]["bias_slope_max_on_fiducials"] = slope;
            js["sensor"]["smoothing_window_px"] = s.sensor.smooth_px;
            js["sensor"]["smoothing_jump"] = s.sensor.smooth_jump * k;
            js["sensor"]["flying_pixel_p"] = s.sensor.fly_p;
            js["sensor"]["multipath"] = s.sensor.multipath * k;
            js["sensor"]["multipath_radius"] = s.sensor.multipath_radius * k;
        }
        js["tolerance"] = {{"translation", (0.1 + bias_tol + std::abs(s.sensor.scale) * rmax) * k},
                           {"rotation_deg", rot_tol}};
        truth["scans"].push_back(js);
    }
    std::ofstream(dir / "job.yaml") << y.str();
    std::ofstream(dir / "truth.json") << truth.dump(1) << "\n";
}

// ---------------------------------------------------------------- self-test (ctest world2_smoke)
int selftest() {
    int fails = 0;
    auto check = [&](bool ok, const std::string& what) {
        std::printf("%s  %s\n", ok ? "ok  " : "FAIL", what.c_str());
        if (!ok) ++fails;
    };
    // 1. shadowing, against geometry worked out by hand: a floor, a 40 mm tall post; camera straight above,
    //    projector 150 mm along +x at the same height. The post's shadow from the projector falls on the
    //    floor on the post's -x side, over a length h * bx / (H - h) seen from the projector.
    {
        std::vector<Body> b = {
            {"floor", "pallet", box({-200, -200, -10}, {200, 200, 0}), Isometry3d::Identity(), -1},
            {"post", "clutter", box({-10, -10, 0}, {10, 10, 40}), Isometry3d::Identity(), -1}};
        RayScene rs(b, {0, 1});
        Sensor s;
        s.W = 400, s.H = 400, s.f = 1000, s.baseline = 150, s.noise = 0, s.bias = 0, s.smooth = 0,
        s.edge_p = 0, s.scale = 0, s.outliers = 0, s.work_distance = 400;
        Rng r(1);
        Isometry3d T = Isometry3d::Identity();
        T.linear() << 1, 0, 0, 0, -1, 0, 0, 0, -1;  // looking down -z, camera x = machine x
        T.translation() = Vector3d(0, 0, 400);
        // the projector sits at camera x + baseline, camera y + 0.08 baseline: machine (150, -12, 400)
        ScanOut o = render(rs, T, s, r);
        int in_shadow = 0, floor_pts = 0;
        // the shadow of the post's top edge x = -10 from the projector at x = 150, z = 400: on the floor at
        // x = 150 - 160 * 400 / 360 = -27.8; the floor between x = -27.8 and -10 (|y| < 9) is unlit.
        for (size_t i = 0; i < o.pts.size(); ++i) {
            Vector3d p = o.T_machine_scan * o.pts[i];
            if (std::abs(p.z()) < 0.01) {
                ++floor_pts;
                if (p.x() > -27.0 && p.x() < -11.0 && std::abs(p.y()) < 8.0) ++in_shadow;
            }
        }
        check(in_shadow == 0,
              "no floor point in the projector's shadow of the post (" + std::to_string(in_shadow) + ")");
        check(floor_pts > 50000, "the lit floor is seen (" + std::to_string(floor_pts) + " points)");
        check(o.shadowed > 100,
              "camera hits that the projector does not see are dropped (" + std::to_string(o.shadowed) + ")");
        // and the floor beyond the post on the +x side is lit: points at x in (11, 27)
        int lit = 0;
        for (auto& q : o.pts) {
            Vector3d p = o.T_machine_scan * q;
            if (std::abs(p.z()) < 0.01 && p.x() > 11 && p.x() < 27 && std::abs(p.y()) < 8) ++lit;
        }
        check(lit > 100,
              "the floor on the projector's side of the post is seen (" + std::to_string(lit) + ")");
        // noise-free points lie on the surfaces: every point on z = 0, z = 40 or a post side
        int off = 0;
        for (auto& q : o.pts) {
            Vector3d p = o.T_machine_scan * q;
            double d = std::min(std::abs(p.z()), mesh_dist(p, b[1].mesh));
            if (d > 0.01) ++off;
        }
        check(off == 0, "noise-free points lie on the surfaces through the truth transform (" +
                            std::to_string(off) + " off)");
    }
    // 2. a small cell: the truth maps each scan's fiducial points onto the fiducial models; traps marked
    for (uint64_t seed : {3ull, 8ull}) {
        Cell c = build_cell(seed, true);
        Cell c2 = build_cell(seed, true);
        bool same = c.scans.size() == c2.scans.size();
        for (size_t i = 0; same && i < c.scans.size(); ++i)
            same = c.scans[i].out.pts.size() == c2.scans[i].out.pts.size() &&
                   (c.scans[i].out.pts.empty() || c.scans[i].out.pts.back() == c2.scans[i].out.pts.back());
        check(same, "seed " + std::to_string(seed) + ": the same seed gives the same cell");
        int meet = 0;  // bodies placed around the part (not the part and what holds it) touch nothing
        for (std::size_t a = 0; a < c.bodies.size(); ++a)
            for (std::size_t b = a + 1; b < c.bodies.size(); ++b) {
                const auto& A = c.bodies[a];
                const auto& B = c.bodies[b];
                const auto placed = [](const Body& x) {
                    return x.kind == "fiducial" || x.kind == "lookalike" || x.name == "second_part" ||
                           x.name == "angle_plate";
                };
                if (A.kind == "pallet" || B.kind == "pallet" || !(placed(A) || placed(B))) continue;
                meet += footprints_meet(footprint(A), footprint(B), 0.0);
            }
        check(meet == 0, "seed " + std::to_string(seed) + ": no two bodies interpenetrate (" +
                             std::to_string(meet) + " pairs of footprints meet)");
        int traps = 0;
        for (auto& s : c.scans) {
            if (!s.trap.empty()) {
                ++traps;
                int n = 0;
                for (int x : s.fid_counts) n += x;
                check(n == 0,
                      "seed " + std::to_string(seed) + ": trap '" + s.trap + "' shows no fiducial point");
                continue;
            }
            // undo the scale error about the scan origin and the bias along each ray, then the distance to
            // the fiducial mesh must be within the noise
            double worst_rms = 0;
            int nchk = 0;
            double ss = 0;
            Isometry3d Tms = s.out.T_machine_scan;
            Vector3d cam_in_scan = Vector3d::Zero();
            for (size_t p = 0; p < s.out.pts.size(); p += 7) {
                int b = s.out.body[p];
                if (b < 0 || c.bodies[size_t(b)].fiducial < 0) continue;
                Vector3d cen(0, 0, s.sensor.work_distance);
                Vector3d q = cen + (s.out.pts[p] - cen) / (1.0 + s.sensor.scale);
                Vector3d ray = (q - cam_in_scan).normalized();
                q -= s.sensor.bias * ray;
                Vector3d pm = Tms * q;
                if (c.rotary) pm = rot_A(s.A).inverse() * pm;
                Vector3d pf = c.bodies[size_t(b)].T.inverse() * pm;
                double d = mesh_dist(pf, c.bodies[size_t(b)].mesh);
                ss += d * d;
                ++nchk;
            }
            if (nchk) worst_rms = std::sqrt(ss / nchk);
            check(nchk == 0 || worst_rms < 2.0 * s.sensor.noise + 0.01,
                  "seed " + std::to_string(seed) + ": fiducial points on the model through the truth, RMS " +
                      std::to_string(worst_rms) + " mm (noise " + std::to_string(s.sensor.noise) + ", " +
                      std::to_string(nchk) + " points)");
        }
        std::printf("seed %llu: %zu scans, %d traps\n", (unsigned long long)seed, c.scans.size(), traps);
    }
    // 3. the depth camera, against the same kind of hand-made geometry: a post at x = -130..-110 on a floor,
    //    the camera above the origin (it sees the post's +x face). Noise, flying pixels and blurring off:
    //    every point, with the bias field read at its pixel taken off along its ray, lies on its surface,
    //    except on the floor within multipath_radius of the post's foot (an inside corner), pushed farther
    //    by at most `multipath`; the post's top edges (convex) are not pushed.
    {
        std::vector<Body> b = {
            {"floor", "pallet", box({-300, -300, -10}, {300, 300, 0}), Isometry3d::Identity(), -1},
            {"post", "clutter", box({-130, -10, 0}, {-110, 10, 40}), Isometry3d::Identity(), -1}};
        RayScene rs(b, {0, 1});
        Sensor s;
        s.depthcam = true;
        s.W = 400, s.H = 400, s.f = 500, s.baseline = 60, s.noise = 0, s.scale = 0, s.work_distance = 400;
        s.bias = 0.8, s.bias_field = 0.6;
        s.field[0] = {1.0, 0.7, 0.0, 0.3}, s.field[1] = {0.5, 0.0, -0.9, 1.0}, s.field[2] = {0.0, 0, 0, 0};
        s.smooth = 0, s.fly_p = 0, s.multipath = 1.2, s.multipath_radius = 4.0;
        Rng r(1);
        Isometry3d T = Isometry3d::Identity();
        T.linear() << 1, 0, 0, 0, -1, 0, 0, 0, -1;
        T.translation() = Vector3d(0, 0, 400);
        ScanOut o = render_depthcam(rs, T, s, r);
        int far_off = 0, near_n = 0, convex_off = 0, convex_n = 0;
        double near_sum = 0, near_max = 0;
        for (size_t i = 0; i < o.pts.size(); ++i) {
            const int u = o.pixel[i] % s.W, v = o.pixel[i] / s.W;
            const Vector3d ray = o.pts[i].normalized();
            const Vector3d p = T * (o.pts[i] - bias_at(s, u + 0.5, v + 0.5) * ray);
            const double off = std::min(std::abs(p.z()), mesh_dist(p, b[1].mesh));
            const bool floor = o.body[i] == 0;
            const double from_face = p.x() + 110;  // floor: distance from the post's +x face
            if (floor && std::abs(p.y()) < 8 && from_face > 0.3 && from_face < 1.5) {
                ++near_n, near_sum += off, near_max = std::max(near_max, off);
            } else if (floor && (from_face > s.multipath_radius + 0.5 || std::abs(p.y()) > 15)) {
                far_off += off > 0.01;
            } else if (!floor && p.z() > 39 && (p.x() > -112 || std::abs(std::abs(p.y()) - 10) < 2)) {
                ++convex_n, convex_off += off > 0.01;
            }
        }
        check(far_off == 0,
              "depthcam: away from inside corners, points less the bias field lie on the surfaces (" +
                  std::to_string(far_off) + " off)");
        check(near_n > 20 && near_sum / near_n > 0.3 * s.multipath && near_max <= s.multipath + 0.01,
              "depthcam: floor 0.3-1.5 mm from the post's foot pushed farther by multipath, mean " +
                  std::to_string(near_n ? near_sum / near_n : 0) + " mm, max " + std::to_string(near_max) +
                  " (at most " + std::to_string(s.multipath) + ", " + std::to_string(near_n) + " points)");
        check(convex_n > 20 && convex_off == 0, "depthcam: the post's convex top edges get no multipath (" +
                                                    std::to_string(convex_off) + " of " +
                                                    std::to_string(convex_n) + " off)");
        // flying pixels at the post's jumps: off every surface, between the top and the floor
        s.fly_p = 1.0;
        ScanOut f = render_depthcam(rs, T, s, r);
        int flying = 0, labelled = 0;
        for (size_t i = 0; i < f.pts.size(); ++i) {
            const Vector3d p = T * f.pts[i];
            if (f.body[i] < 0) ++flying, labelled += p.z() > 0.5 && p.z() < 40;
        }
        check(flying > 50 && labelled > 0.8 * flying,
              "depthcam: flying pixels at depth jumps (" + std::to_string(flying) + ", " +
                  std::to_string(labelled) + " between the floor and the top)");
    }
    // 4. a small depth-camera cell, noise off: its fiducial points, with the scale and the bias field at
    //    their pixels taken off, lie on the fiducials except where the blurring and multipath move them (at
    //    most smooth_jump + multipath), and their median within 0.1 mm (the blurred bands along the edges
    //    and the multipath bands in the inside corners, a few mm wide each, cover up to half a fiducial's
    //    points); the raw points' distances are printed (off the CAD by 0.7-2 mm in places).
    g_depthcam = g_no_noise = true;
    for (uint64_t seed : {3ull}) {
        Cell c = build_cell(seed, false);
        for (auto& s : c.scans) {
            if (!s.trap.empty()) continue;
            std::vector<double> on, raw;
            double bound = s.sensor.smooth_jump + s.sensor.multipath + 0.05, worst = 0;
            for (size_t p = 0; p < s.out.pts.size(); p += 23) {
                int b = s.out.body[p];
                if (b < 0 || c.bodies[size_t(b)].fiducial < 0) continue;
                const Vector3d cen(0, 0, s.sensor.work_distance);
                Vector3d q = cen + (s.out.pts[p] - cen) / (1.0 + s.sensor.scale);
                const int pix = s.out.pixel[p];
                const Vector3d ray = q.normalized();
                const auto model_dist = [&](const Vector3d& x) {
                    Vector3d pm = s.out.T_machine_scan * x;
                    if (c.rotary) pm = rot_A(s.A).inverse() * pm;
                    return mesh_dist(c.bodies[size_t(b)].T.inverse() * pm, c.bodies[size_t(b)].mesh);
                };
                raw.push_back(model_dist(q));
                q -= bias_at(s.sensor, pix % s.sensor.W + 0.5, pix / s.sensor.W + 0.5) * ray;
                on.push_back(model_dist(q));
                worst = std::max(worst, on.back());
            }
            if (on.size() < 20) continue;
            std::sort(on.begin(), on.end());
            std::sort(raw.begin(), raw.end());
            const double med = on[on.size() / 2], raw90 = raw[raw.size() * 9 / 10];
            check(med < 0.1 && worst <= bound,
                  "seed " + std::to_string(seed) +
                      " depthcam: fiducial points less the bias field on the model, "
                      "median " +
                      std::to_string(med) + " mm, max " + std::to_string(worst) + " (bound " +
                      std::to_string(bound) + "); raw: 90 % within " + std::to_string(raw90) + " mm, max " +
                      std::to_string(raw.back()) + " (" + std::to_string(on.size()) + " points)");
        }
    }
    g_depthcam = g_no_noise = false;
    std::printf("%s\n", fails ? "SELFTEST FAILED" : "selftest passed");
    return fails ? 1 : 0;
}

}  // namespace

int main(int argc, char** argv) {
    std::string out, unit = "mm";
    uint64_t seed = 1;
    bool small = false;
    for (int i = 1; i < argc; ++i) {
        std::string a = argv[i];
        auto next = [&]() -> std::string {
            if (i + 1 >= argc) throw std::runtime_error(a + " needs a value");
            return argv[++i];
        };
        try {
            if (a == "--out")
                out = next();
            else if (a == "--seed")
                seed = std::stoull(next());
            else if (a == "--unit")
                unit = next();
            else if (a == "--small")
                small = true;
            else if (a == "--ideal")
                g_ideal = true;
            else if (a == "--no-scale")
                g_no_scale = true;
            else if (a == "--sensor") {
                const std::string v = next();
                if (v != "scanner" && v != "depthcam")
                    throw std::runtime_error("--sensor " + v + ": scanner or depthcam");
                g_depthcam = v == "depthcam";
            } else if (a == "--selftest")
                return selftest();
            else if (a == "-h" || a == "--help") {
                std::printf(
                    "partloc_world2 --out DIR [--seed N] [--unit um|mm|m|in] [--small] "
                    "[--ideal] [--no-scale] [--sensor scanner|depthcam]\npartloc_world2 --selftest\n");
                return 0;
            } else
                throw std::runtime_error("unknown option " + a);
        } catch (std::exception& e) {
            std::fprintf(stderr, "partloc_world2: %s\n", e.what());
            return 2;
        }
    }
    if (out.empty()) {
        std::fprintf(stderr, "partloc_world2: --out DIR is required\n");
        return 2;
    }
    try {
        unit_factor(unit);
        Cell c = build_cell(seed, small);
        write_cell(c, out, seed, unit);
        int traps = 0;
        for (auto& s : c.scans) traps += !s.trap.empty();
        std::printf("partloc_world2: seed %llu: %s%s, %zu fiducials, %zu scans (%d traps) -> %s\n",
                    (unsigned long long)seed, c.layout.c_str(), c.rotary ? ", rotary A" : "",
                    c.fid_desc.size(), c.scans.size(), traps, out.c_str());
    } catch (std::exception& e) {
        std::fprintf(stderr, "partloc_world2: %s\n", e.what());
        return 1;
    }
    return 0;
}
