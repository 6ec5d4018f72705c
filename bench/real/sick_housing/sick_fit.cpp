// An independent check of partloc on the SICK housing scan (bench/real/sick_housing/README.md): Open3D 0.16's
// global registration (FPFH + RANSAC, several seeds) and point-to-plane ICP find the housing CAD in the scan,
// and `eval` judges any pose T_scan_model by the fit: signed point-to-mesh distances, coverage of the CAD's
// visible surface, residuals by distance to sharp edges and by incidence angle, and the scan's local scatter.
// The sensor sits at the scan frame's origin (a time-of-flight camera's coordinates).
//
//   sick_fit register MODEL SCAN [SEEDS] [VOXEL]      prints every seed's pose and the best one
//   sick_fit noplane SCAN OUT.ply THRESHOLD           the dominant plane removed (the SICK sample's step)
//   sick_fit multistart MODEL SCAN N cx cy cz         ICP from N random rotations about the point c
//   sick_fit icp MODEL SCAN m00..m33                 the ICP alone from a given T_scan_model
//   sick_fit eval MODEL SCAN m00 m01 ... m33          16 numbers, row-major T_scan_model
//   sick_fit compare m00..m33 n00..n33 MODEL         rotation and translation differences of two poses
//
// Build: g++ -O2 -std=c++17 sick_fit.cpp -I/usr/include/eigen3 -lOpen3D -lfmt -o sick_fit
#include <open3d/Open3D.h>
#include <open3d/t/geometry/RaycastingScene.h>

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <map>
#include <memory>
#include <numeric>
#include <random>
#include <string>
#include <vector>

namespace reg = open3d::pipelines::registration;
using Eigen::Matrix4d;
using Eigen::Vector3d;
using open3d::geometry::KDTreeFlann;
using open3d::geometry::PointCloud;
using open3d::geometry::TriangleMesh;

namespace {

double median(std::vector<double> v) {
    if (v.empty()) return NAN;
    std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
    return v[v.size() / 2];
}
// 1.4826 x the median absolute deviation: the sigma of a normal distribution with that MAD.
double robust_sigma(const std::vector<double>& v) {
    const double m = median(v);
    std::vector<double> a;
    for (double x : v) a.push_back(std::abs(x - m));
    return 1.4826 * median(a);
}
double share_within(const std::vector<double>& v, double t) {
    if (v.empty()) return NAN;
    return double(std::count_if(v.begin(), v.end(), [t](double x) { return std::abs(x) <= t; })) / v.size();
}

// Area-weighted samples of the mesh with their triangle and the triangle's normal.
struct Samples {
    std::vector<Vector3d> p, n;
    std::vector<int> tri;
};
Samples sample_mesh(const TriangleMesh& m, double per_mm2, unsigned seed) {
    std::mt19937 rng(seed);
    std::uniform_real_distribution<double> u(0, 1);
    Samples s;
    for (size_t t = 0; t < m.triangles_.size(); ++t) {
        const auto& f = m.triangles_[t];
        const Vector3d a = m.vertices_[f(0)], b = m.vertices_[f(1)], c = m.vertices_[f(2)];
        const double area = 0.5 * (b - a).cross(c - a).norm();
        double want = area * per_mm2;
        int k = int(want);
        if (u(rng) < want - k) ++k;
        for (int i = 0; i < k; ++i) {
            double r1 = std::sqrt(u(rng)), r2 = u(rng);
            s.p.push_back((1 - r1) * a + r1 * (1 - r2) * b + r1 * r2 * c);
            s.n.push_back(m.triangle_normals_[t]);
            s.tri.push_back(int(t));
        }
    }
    return s;
}

std::shared_ptr<TriangleMesh> load_mesh(const std::string& path) {
    auto m = open3d::io::CreateMeshFromFile(path);
    if (!m || m->triangles_.empty()) {
        std::fprintf(stderr, "%s: no triangles\n", path.c_str());
        std::exit(2);
    }
    m->ComputeTriangleNormals();
    return m;
}
std::shared_ptr<PointCloud> load_cloud(const std::string& path) {
    auto c = open3d::io::CreatePointCloudFromFile(path);
    if (!c || c->points_.empty()) {
        std::fprintf(stderr, "%s: no points\n", path.c_str());
        std::exit(2);
    }
    return c;
}

Matrix4d parse_matrix(char** a) {
    Matrix4d T;
    for (int i = 0; i < 16; ++i) T(i / 4, i % 4) = std::atof(a[i]);
    return T;
}
void print_matrix(const char* name, const Matrix4d& T) {
    std::printf("%s [", name);
    for (int r = 0; r < 4; ++r)
        std::printf("[%.6f, %.6f, %.6f, %.4f]%s", T(r, 0), T(r, 1), T(r, 2), T(r, 3), r < 3 ? ", " : "]\n");
}

// ---- register --------------------------------------------------------------------------------------------

struct Fit {
    Matrix4d T_scan_model = Matrix4d::Identity();
    double ransac_fitness = 0, ransac_rmse = 0, fitness = 0, rmse = 0;
    int inliers = 0;
};

// Point-to-plane ICP of the scan (source) onto the dense CAD samples (target), Tukey-weighted, with a
// shrinking correspondence distance; scan points off the housing (background) fall out by distance.
Fit refine(const PointCloud& scan, const PointCloud& model_dense, const Matrix4d& T_scan_model0) {
    Matrix4d T_model_scan = T_scan_model0.inverse();
    for (double d : {10.0, 6.0, 4.0, 3.0}) {
        auto est = reg::TransformationEstimationPointToPlane(std::make_shared<reg::TukeyLoss>(d));
        auto r = reg::RegistrationICP(scan, model_dense, d, T_model_scan, est,
                                      reg::ICPConvergenceCriteria(1e-7, 1e-7, 60));
        T_model_scan = r.transformation_;
    }
    auto ev = reg::EvaluateRegistration(scan, model_dense, 3.0, T_model_scan);
    Fit f;
    f.T_scan_model = T_model_scan.inverse();
    f.fitness = ev.fitness_;  // share of all scan points within 3 mm of the CAD
    f.rmse = ev.inlier_rmse_;
    f.inliers = int(ev.correspondence_set_.size());
    return f;
}

int cmd_register(const std::string& model_path, const std::string& scan_path, int seeds, double voxel) {
    auto mesh = load_mesh(model_path);
    auto scan = load_cloud(scan_path);
    Samples s = sample_mesh(*mesh, 4.0, 1);  // 4 samples per mm^2: 0.5 mm apart
    PointCloud model_dense;
    model_dense.points_ = s.p;
    model_dense.normals_ = s.n;
    auto model_down = model_dense.VoxelDownSample(voxel);
    auto scan_down = scan->VoxelDownSample(voxel);
    const auto normal_search = open3d::geometry::KDTreeSearchParamHybrid(2 * voxel, 30);
    scan_down->EstimateNormals(normal_search);
    scan_down->OrientNormalsTowardsCameraLocation(Vector3d::Zero());
    model_down->EstimateNormals(normal_search);  // from the points, as for the scan
    model_down->OrientNormalsToAlignWithDirection();
    // Orient the model's normals by the CAD's own (outward) normals: nearest dense sample.
    KDTreeFlann dense_tree(model_dense);
    for (size_t i = 0; i < model_down->points_.size(); ++i) {
        std::vector<int> idx(1);
        std::vector<double> d2(1);
        dense_tree.SearchKNN(model_down->points_[i], 1, idx, d2);
        if (model_down->normals_[i].dot(model_dense.normals_[idx[0]]) < 0) model_down->normals_[i] *= -1;
    }
    const auto fpfh_search = open3d::geometry::KDTreeSearchParamHybrid(5 * voxel, 100);
    auto f_model = reg::ComputeFPFHFeature(*model_down, fpfh_search);
    auto f_scan = reg::ComputeFPFHFeature(*scan_down, fpfh_search);
    std::printf("model %zu dense samples, %zu at voxel %.2f mm; scan %zu points, %zu at voxel\n",
                model_dense.points_.size(), model_down->points_.size(), voxel, scan->points_.size(),
                scan_down->points_.size());

    std::vector<std::reference_wrapper<const reg::CorrespondenceChecker>> checkers;
    reg::CorrespondenceCheckerBasedOnEdgeLength edge(0.9);
    reg::CorrespondenceCheckerBasedOnDistance dist(1.5 * voxel);
    checkers.push_back(edge);
    checkers.push_back(dist);
    Fit best;
    int best_seed = -1;
    for (int seed = 1; seed <= seeds; ++seed) {
        for (bool mutual : {false, true}) {
            open3d::utility::random::Seed(seed);
            auto r = reg::RegistrationRANSACBasedOnFeatureMatching(
                *model_down, *scan_down, *f_model, *f_scan, mutual, 1.5 * voxel,
                reg::TransformationEstimationPointToPoint(false), 3, checkers,
                reg::RANSACConvergenceCriteria(100000, 0.999));
            Fit f = refine(*scan, model_dense, r.transformation_);
            f.ransac_fitness = r.fitness_;
            f.ransac_rmse = r.inlier_rmse_;
            const Matrix4d& T = f.T_scan_model;
            std::printf(
                "seed %2d mutual %d  ransac fitness %.3f rmse %.2f  ->  icp inliers(3mm) %4d fitness %.4f "
                "rmse %.3f  t [%.2f %.2f %.2f]\n",
                seed, int(mutual), f.ransac_fitness, f.ransac_rmse, f.inliers, f.fitness, f.rmse, T(0, 3),
                T(1, 3), T(2, 3));
            if (f.inliers > best.inliers || (f.inliers == best.inliers && f.rmse < best.rmse)) {
                best = f;
                best_seed = seed * 10 + int(mutual);
            }
        }
    }
    std::printf("best: seed %d mutual %d inliers %d fitness %.4f rmse %.3f\n", best_seed / 10, best_seed % 10,
                best.inliers, best.fitness, best.rmse);
    print_matrix("T_scan_model", best.T_scan_model);
    std::printf("T_scan_model_flat");
    for (int i = 0; i < 16; ++i) std::printf(" %.9g", best.T_scan_model(i / 4, i % 4));
    std::printf("\n");
    return 0;
}

// Multi-start ICP: N random rotations (uniform quaternions) with the CAD box centre at the point C; ranked
// by the scan points within 3 mm of the CAD after ICP. No features: an independent check of the RANSAC.
int cmd_multistart(const std::string& model_path, const std::string& scan_path, int starts,
                   const Vector3d& C) {
    auto mesh = load_mesh(model_path);
    auto scan = load_cloud(scan_path);
    Samples s = sample_mesh(*mesh, 4.0, 1);
    PointCloud model_dense;
    model_dense.points_ = s.p;
    model_dense.normals_ = s.n;
    // Speed: the CAD samples thinned to 1 mm, the scan to the points within 120 mm of C.
    auto model_1mm = model_dense.VoxelDownSample(1.0);
    model_dense = *model_1mm;
    std::vector<size_t> near_c;
    for (size_t i = 0; i < scan->points_.size(); ++i)
        if ((scan->points_[i] - C).norm() < 120) near_c.push_back(i);
    scan = scan->SelectByIndex(near_c);
    const Vector3d c = mesh->GetAxisAlignedBoundingBox().GetCenter();
    std::mt19937 rng(12345);
    std::normal_distribution<double> g(0, 1);
    std::vector<Fit> fits;
    for (int k = 0; k < starts; ++k) {
        Eigen::Quaterniond q(g(rng), g(rng), g(rng), g(rng));
        q.normalize();
        Matrix4d T = Matrix4d::Identity();
        T.block<3, 3>(0, 0) = q.toRotationMatrix();
        T.block<3, 1>(0, 3) = C - q.toRotationMatrix() * c;
        fits.push_back(refine(*scan, model_dense, T));
    }
    std::sort(fits.begin(), fits.end(), [](const Fit& a, const Fit& b) { return a.inliers > b.inliers; });
    std::vector<Fit> distinct;
    for (const Fit& f : fits) {
        bool dup = false;
        for (const Fit& e : distinct) {
            Eigen::Matrix3d dR =
                e.T_scan_model.block<3, 3>(0, 0).transpose() * f.T_scan_model.block<3, 3>(0, 0);
            double ang = std::acos(std::clamp((dR.trace() - 1) / 2, -1.0, 1.0)) * 180 / M_PI;
            double dc = ((e.T_scan_model - f.T_scan_model) * c.homogeneous()).head<3>().norm();
            if (ang < 3 && dc < 3) dup = true;
        }
        if (!dup) distinct.push_back(f);
        if (distinct.size() == 8) break;
    }
    for (size_t i = 0; i < distinct.size(); ++i) {
        const Fit& f = distinct[i];
        int same = 0;
        for (const Fit& h : fits) {
            Eigen::Matrix3d dR =
                h.T_scan_model.block<3, 3>(0, 0).transpose() * f.T_scan_model.block<3, 3>(0, 0);
            double ang = std::acos(std::clamp((dR.trace() - 1) / 2, -1.0, 1.0)) * 180 / M_PI;
            if (ang < 3 && ((h.T_scan_model - f.T_scan_model) * c.homogeneous()).head<3>().norm() < 3) ++same;
        }
        std::printf("#%zu inliers(3mm) %d fitness %.4f rmse %.3f  reached from %d of %d starts\n  flat", i,
                    f.inliers, f.fitness, f.rmse, same, starts);
        for (int j = 0; j < 16; ++j) std::printf(" %.9g", f.T_scan_model(j / 4, j % 4));
        std::printf("\n");
    }
    return 0;
}

// The SICK sample's own pre-processing (its scripts/main.lua, step 4-5): the dominant plane, fitted with a 15
// mm distance threshold, removed; what is left goes to the matcher.
int cmd_noplane(const std::string& scan_path, const std::string& out, double threshold) {
    auto scan = load_cloud(scan_path);
    open3d::utility::random::Seed(1);
    auto [plane, in] = scan->SegmentPlane(threshold, 3, 2000);
    auto rest = scan->SelectByIndex(in, true);
    std::printf("plane %.4f %.4f %.4f %.2f: %zu of %zu points removed, %zu left\n", plane(0), plane(1),
                plane(2), plane(3), in.size(), scan->points_.size(), rest->points_.size());
    open3d::io::WritePointCloud(out, *rest, {true});
    return 0;
}

// ---- eval ------------------------------------------------------------------------------------------------

struct Edges {  // sharp edges of the mesh (dihedral above 30 degrees), sampled every 0.5 mm
    PointCloud pts;
    std::vector<int> concave;  // per sample: 1 concave (an inside corner), 0 convex
};
Edges sharp_edges(const TriangleMesh& m) {
    std::map<std::pair<int, int>, std::vector<int>> edge_tris;
    for (size_t t = 0; t < m.triangles_.size(); ++t)
        for (int k = 0; k < 3; ++k) {
            int a = m.triangles_[t](k), b = m.triangles_[t]((k + 1) % 3);
            edge_tris[{std::min(a, b), std::max(a, b)}].push_back(int(t));
        }
    Edges e;
    const double cos30 = std::cos(30.0 * M_PI / 180);
    for (const auto& [ab, ts] : edge_tris) {
        if (ts.size() != 2) continue;
        const Vector3d n1 = m.triangle_normals_[ts[0]], n2 = m.triangle_normals_[ts[1]];
        if (n1.dot(n2) > cos30) continue;
        // Concave when the second triangle's far vertex lies on the outer side of the first's plane.
        const auto& f2 = m.triangles_[ts[1]];
        int far = f2(0) + f2(1) + f2(2) - ab.first - ab.second;
        const Vector3d a = m.vertices_[ab.first], b = m.vertices_[ab.second];
        int concave = n1.dot(m.vertices_[far] - a) > 0 ? 1 : 0;
        int k = std::max(1, int((b - a).norm() / 0.5));
        for (int i = 0; i <= k; ++i) {
            e.pts.points_.push_back(a + (b - a) * (double(i) / k));
            e.concave.push_back(concave);
        }
    }
    return e;
}

// Planar faces: triangles grouped by adjacency (shared edge) and normal within 5 degrees of the seed's.
std::vector<int> planar_faces(const TriangleMesh& m, int& nfaces) {
    std::map<std::pair<int, int>, std::vector<int>> edge_tris;
    for (size_t t = 0; t < m.triangles_.size(); ++t)
        for (int k = 0; k < 3; ++k) {
            int a = m.triangles_[t](k), b = m.triangles_[t]((k + 1) % 3);
            edge_tris[{std::min(a, b), std::max(a, b)}].push_back(int(t));
        }
    std::vector<std::vector<int>> nb(m.triangles_.size());
    for (const auto& [ab, ts] : edge_tris)
        for (int i : ts)
            for (int j : ts)
                if (i != j) nb[i].push_back(j);
    std::vector<int> face(m.triangles_.size(), -1);
    const double cos5 = std::cos(5.0 * M_PI / 180);
    nfaces = 0;
    for (size_t s = 0; s < face.size(); ++s) {
        if (face[s] >= 0) continue;
        const Vector3d ns = m.triangle_normals_[s];
        std::vector<int> stack{int(s)};
        face[s] = nfaces;
        while (!stack.empty()) {
            int t = stack.back();
            stack.pop_back();
            for (int u : nb[t])
                if (face[u] < 0 && m.triangle_normals_[u].dot(ns) > cos5) {
                    face[u] = nfaces;
                    stack.push_back(u);
                }
        }
        ++nfaces;
    }
    return face;
}

// Nearest CAD range per direction from the eye (gnomonic grid of pixel size `pixel` rad about `axis`).
struct ZBuffer {
    Vector3d eye, a, b, c;
    double pixel;
    std::map<std::pair<int, int>, double> zmin;
    ZBuffer(const std::vector<Vector3d>& pts, const Vector3d& eye_, const Vector3d& axis, double pixel_)
        : eye(eye_), c(axis), pixel(pixel_) {
        a = c.unitOrthogonal();
        b = c.cross(a);
        for (const auto& p : pts) {
            auto k = key(p);
            double r = (p - eye).norm();
            auto it = zmin.find(k);
            if (it == zmin.end() || r < it->second) zmin[k] = r;
        }
    }
    std::pair<int, int> key(const Vector3d& p) const {
        Vector3d v = p - eye;
        double z = v.dot(c);
        return {int(std::floor(v.dot(a) / z / pixel)), int(std::floor(v.dot(b) / z / pixel))};
    }
    double nearest(const Vector3d& p) const {  // inf where the CAD does not cover the direction
        auto it = zmin.find(key(p));
        return it == zmin.end() ? INFINITY : it->second;
    }
};

void print_stats(const char* label, const std::vector<double>& d) {
    std::printf("  %-34s n %5zu  median %+7.3f  robust sigma %6.3f  within 1/2/3 mm %5.1f %5.1f %5.1f %%\n",
                label, d.size(), median(d), robust_sigma(d), 100 * share_within(d, 1),
                100 * share_within(d, 2), 100 * share_within(d, 3));
}

int cmd_eval(const std::string& model_path, const std::string& scan_path, const Matrix4d& T_scan_model) {
    auto mesh = load_mesh(model_path);
    auto scan = load_cloud(scan_path);
    const Matrix4d T_model_scan = T_scan_model.inverse();
    const Vector3d eye = T_model_scan.block<3, 1>(0, 3);  // the sensor in the model frame

    open3d::t::geometry::RaycastingScene rays;
    rays.AddTriangles(open3d::t::geometry::TriangleMesh::FromLegacy(*mesh));

    // Outward normals? Share of the area whose normal points away from the centroid.
    {
        Vector3d c = mesh->GetCenter();
        double out = 0, all = 0;
        for (size_t t = 0; t < mesh->triangles_.size(); ++t) {
            const auto& f = mesh->triangles_[t];
            Vector3d a = mesh->vertices_[f(0)], b = mesh->vertices_[f(1)], cc = mesh->vertices_[f(2)];
            double area = 0.5 * (b - a).cross(cc - a).norm();
            all += area;
            if (mesh->triangle_normals_[t].dot((a + b + cc) / 3 - c) > 0) out += area;
        }
        std::printf("CAD: %zu triangles, area %.0f mm^2, %.1f %% of it with normals away from the centroid\n",
                    mesh->triangles_.size(), all, 100 * out / all);
    }
    const auto bb = mesh->GetAxisAlignedBoundingBox();
    const double margin = 5.0;
    std::vector<Vector3d> pm;  // scan points in the model frame, within the CAD's box + margin
    for (const auto& p : scan->points_) {
        Vector3d q = (T_model_scan * p.homogeneous()).head<3>();
        if ((q.array() >= bb.min_bound_.array() - margin).all() &&
            (q.array() <= bb.max_bound_.array() + margin).all())
            pm.push_back(q);
    }
    const size_t n = pm.size();
    std::printf("scan points in the CAD box + %.0f mm: %zu of %zu\n", margin, n, scan->points_.size());
    if (n == 0) return 3;

    namespace core = open3d::core;
    core::Tensor q({int64_t(n), 3}, core::Float32);
    for (size_t i = 0; i < n; ++i)
        for (int k = 0; k < 3; ++k) q[i][k] = float(pm[i](k));
    auto cp = rays.ComputeClosestPoints(q);
    const float* cpp = cp["points"].Contiguous().GetDataPtr<float>();
    const uint32_t* cpid = cp["primitive_ids"].Contiguous().GetDataPtr<uint32_t>();
    // Visibility: Open3D 0.16 RaycastingScene::CastRays finds no hit at all in this build (t_hit inf even
    // for rays through the CAD centre), so a z-buffer of dense CAD samples seen from the sensor stands in.
    Samples s = sample_mesh(*mesh, 4.0, 7);
    const ZBuffer zb(s.p, eye, (mesh->GetCenter() - eye).normalized(),
                     0.6 / (mesh->GetCenter() - eye).norm());
    const size_t ns = s.p.size();

    Edges edges = sharp_edges(*mesh);
    KDTreeFlann edge_tree(edges.pts);
    int nfaces = 0;
    std::vector<int> face = planar_faces(*mesh, nfaces);

    std::vector<double> d(n), edge_dist(n), incid(n);
    std::vector<int> edge_concave(n), fid(n);
    int seen_through = 0, seen_through_3 = 0;
    for (size_t i = 0; i < n; ++i) {
        Vector3d c(cpp[3 * i], cpp[3 * i + 1], cpp[3 * i + 2]);
        const Vector3d nrm = mesh->triangle_normals_[cpid[i]];
        d[i] = (pm[i] - c).dot(nrm) >= 0 ? (pm[i] - c).norm() : -(pm[i] - c).norm();
        std::vector<int> idx(1);
        std::vector<double> d2(1);
        edge_tree.SearchKNN(c, 1, idx, d2);
        edge_dist[i] = std::sqrt(d2[0]);
        edge_concave[i] = edges.concave[idx[0]];
        incid[i] = std::acos(std::min(1.0, std::abs(nrm.dot((pm[i] - eye).normalized())))) * 180 / M_PI;
        fid[i] = face[cpid[i]];
        const double range = (pm[i] - eye).norm();
        if (zb.nearest(pm[i]) < range - 1.0) ++seen_through;  // the ray passes the CAD first
        if (zb.nearest(pm[i]) < range - 3.0) ++seen_through_3;
    }

    std::printf("signed point-to-mesh distance (mm, + outside the CAD):\n");
    print_stats("all points in the box", d);
    std::vector<double> near;
    for (double x : d)
        if (std::abs(x) <= 10) near.push_back(x);
    print_stats("those within 10 mm of the CAD", near);
    std::printf(
        "  seen through the CAD (ray meets the CAD > 1 mm / > 3 mm before the point): %d / %d of %zu\n",
        seen_through, seen_through_3, n);

    std::printf("by distance of the closest CAD point to a sharp edge (only |d| <= 10 mm):\n");
    const double eb[] = {0, 2, 5, 10, 1e9};
    for (int b = 0; b < 4; ++b)
        for (int cc = 0; cc < 2; ++cc) {
            std::vector<double> v;
            for (size_t i = 0; i < n; ++i)
                if (std::abs(d[i]) <= 10 && edge_dist[i] >= eb[b] && edge_dist[i] < eb[b + 1] &&
                    edge_concave[i] == cc)
                    v.push_back(d[i]);
            char lab[64];
            std::snprintf(lab, sizeof lab, "edge %g-%g mm, %s", eb[b], eb[b + 1] > 1e8 ? 999 : eb[b + 1],
                          cc ? "concave" : "convex");
            if (!v.empty()) print_stats(lab, v);
        }
    std::printf("by incidence angle (ray vs CAD normal; only |d| <= 10 mm, > 5 mm from edges):\n");
    const double ab[] = {0, 30, 50, 70, 90.1};
    for (int b = 0; b < 4; ++b) {
        std::vector<double> v;
        for (size_t i = 0; i < n; ++i)
            if (std::abs(d[i]) <= 10 && edge_dist[i] >= 5 && incid[i] >= ab[b] && incid[i] < ab[b + 1])
                v.push_back(d[i]);
        char lab[64];
        std::snprintf(lab, sizeof lab, "incidence %g-%g deg", ab[b], ab[b + 1] > 90 ? 90 : ab[b + 1]);
        if (!v.empty()) print_stats(lab, v);
    }

    // Visible surface: samples facing the sensor whose ray from the sensor meets the CAD first at them.
    // (Samples s and the z-buffer zb are made above.)
    PointCloud near_cloud;
    for (size_t i = 0; i < n; ++i)
        if (std::abs(d[i]) <= 3) near_cloud.points_.push_back(pm[i]);
    KDTreeFlann near_tree(near_cloud);
    std::vector<double> face_vis_area(nfaces, 0.0);
    std::vector<int> face_pts(nfaces, 0);
    for (size_t i = 0; i < n; ++i)
        if (std::abs(d[i]) <= 3) ++face_pts[fid[i]];
    size_t vis = 0;
    std::map<double, size_t> covered;
    for (size_t i = 0; i < ns; ++i) {
        const double range = (s.p[i] - eye).norm();
        if (s.n[i].dot(eye - s.p[i]) <= 0 || range > zb.nearest(s.p[i]) + 0.3) continue;
        ++vis;
        face_vis_area[face[s.tri[i]]] += 0.25;  // four samples per mm^2
        for (double r : {3.0, 5.0, 7.5}) {
            std::vector<int> idx;
            std::vector<double> d2;
            if (!near_cloud.points_.empty() && near_tree.SearchRadius(s.p[i], r, idx, d2) > 0) ++covered[r];
        }
    }
    std::printf(
        "visible CAD surface from the sensor: about %.0f mm^2 of %.0f; with a scan point (|d| <= 3 mm) "
        "within "
        "3 / 5 / 7.5 mm: %.1f / %.1f / %.1f %%\n",
        vis / 4.0, ns / 4.0, 100.0 * covered[3.0] / vis, 100.0 * covered[5.0] / vis,
        100.0 * covered[7.5] / vis);
    int big = 0, big_hit = 0, big_hit3 = 0;
    std::vector<int> order(nfaces);
    std::iota(order.begin(), order.end(), 0);
    std::sort(order.begin(), order.end(), [&](int a, int b) { return face_vis_area[a] > face_vis_area[b]; });
    for (int f : order) {
        if (face_vis_area[f] < 100) break;
        ++big;
        if (face_pts[f] > 0) ++big_hit;
        if (face_pts[f] >= 3) ++big_hit3;
    }
    std::printf(
        "planar faces (5 deg) with >= 100 mm^2 visible: %d; with >= 1 / >= 3 scan points (|d| <= 3 mm): %d / "
        "%d\n",
        big, big_hit, big_hit3);

    // Per large visible face: scan points on it, their offset from the CAD plane and their own plane's
    // scatter.
    std::printf(
        "largest visible faces (points with |d| <= 5 mm, closest CAD point > 3 mm from a sharp edge):\n");
    const PointCloud box_cloud(pm);
    KDTreeFlann scan_tree(box_cloud);
    std::vector<double> local_all, cad_all;
    for (int k = 0; k < std::min<int>(8, int(order.size())); ++k) {
        const int f = order[k];
        if (face_vis_area[f] < 100) break;
        std::vector<int> on;
        for (size_t i = 0; i < n; ++i)
            if (fid[i] == f && std::abs(d[i]) <= 5 && edge_dist[i] > 3) on.push_back(int(i));
        std::vector<double> df;
        Vector3d nf = Vector3d::Zero();
        for (size_t t = 0; t < mesh->triangles_.size(); ++t)
            if (face[t] == f) nf = mesh->triangle_normals_[t];
        for (int i : on) df.push_back(d[i]);
        // One plane through the face's points: its scatter is the sensor's noise across the face.
        double plane_sigma = NAN, tilt = NAN;
        if (on.size() >= 6) {
            Vector3d mu = Vector3d::Zero();
            for (int i : on) mu += pm[i];
            mu /= on.size();
            Eigen::Matrix3d C = Eigen::Matrix3d::Zero();
            for (int i : on) C += (pm[i] - mu) * (pm[i] - mu).transpose();
            Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(C);
            Vector3d pn = es.eigenvectors().col(0);
            std::vector<double> r;
            for (int i : on) r.push_back((pm[i] - mu).dot(pn));
            plane_sigma = robust_sigma(r);
            tilt = std::acos(std::min(1.0, std::abs(pn.dot(nf)))) * 180 / M_PI;
        }
        double inc = 0;
        for (int i : on) inc += incid[i];
        std::printf(
            "  face %4d normal [%+.2f %+.2f %+.2f] visible %5.0f mm^2  pts %3zu  incidence %4.1f deg  "
            "median d %+6.3f  robust sigma to CAD %5.3f  own-plane robust sigma %5.3f  plane tilt %4.1f "
            "deg\n",
            f, nf(0), nf(1), nf(2), face_vis_area[f], on.size(), on.empty() ? NAN : inc / on.size(),
            median(df), robust_sigma(df), plane_sigma, tilt);
        // Local scatter: the 8 nearest scan points on the same face, a plane through them.
        for (int i : on) {
            std::vector<int> idx;
            std::vector<double> d2;
            scan_tree.SearchKNN(pm[i], 9, idx, d2);
            std::vector<int> nb;
            for (int j : idx)
                if (fid[j] == f && std::abs(d[j]) <= 5 && edge_dist[j] > 3) nb.push_back(j);
            if (nb.size() < 7) continue;
            Vector3d mu = Vector3d::Zero();
            for (int j : nb) mu += pm[j];
            mu /= nb.size();
            Eigen::Matrix3d C = Eigen::Matrix3d::Zero();
            for (int j : nb) C += (pm[j] - mu) * (pm[j] - mu).transpose();
            Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(C);
            // residual sigma of the centre point's plane, corrected for the 3 fitted parameters
            local_all.push_back(std::sqrt(std::max(0.0, es.eigenvalues()(0)) / (nb.size() - 3)));
            cad_all.push_back(d[i]);
        }
    }
    std::printf(
        "local scatter (plane through 7-9 neighbours on one face, dof-corrected): n %zu  median sigma %.3f "
        "mm\n",
        local_all.size(), median(local_all));
    std::printf("  the same points against the CAD: median d %+.3f  robust sigma %.3f mm\n", median(cad_all),
                robust_sigma(cad_all));

    // Where the residuals are large: the |d| > 3 mm points, by what they are near.
    int big_res = 0, big_edge = 0, big_concave = 0, big_inside = 0;
    for (size_t i = 0; i < n; ++i)
        if (std::abs(d[i]) > 3 && std::abs(d[i]) <= 10) {
            ++big_res;
            if (edge_dist[i] < 5) ++big_edge;
            if (edge_dist[i] < 5 && edge_concave[i]) ++big_concave;
            if (d[i] < 0) ++big_inside;
        }
    std::printf(
        "points with 3 < |d| <= 10 mm: %d; of them within 5 mm of a sharp edge %d (concave %d); inside the "
        "CAD %d\n",
        big_res, big_edge, big_concave, big_inside);
    return 0;
}

int cmd_compare(const Matrix4d& A, const Matrix4d& B, const std::string& model_path) {
    auto mesh = load_mesh(model_path);
    const Vector3d c = mesh->GetAxisAlignedBoundingBox().GetCenter();
    const Eigen::Matrix3d dR = A.block<3, 3>(0, 0).transpose() * B.block<3, 3>(0, 0);
    const double ang = std::acos(std::clamp((dR.trace() - 1) / 2, -1.0, 1.0)) * 180 / M_PI;
    const Vector3d dt = B.block<3, 1>(0, 3) - A.block<3, 1>(0, 3);
    const Vector3d dc = (B * c.homogeneous() - A * c.homogeneous()).head<3>();
    std::printf(
        "rotation difference %.3f deg; translation difference [%.3f %.3f %.3f] |%.3f| mm; the CAD box "
        "centre [%.1f %.1f %.1f] moves by %.3f mm\n",
        ang, dt(0), dt(1), dt(2), dt.norm(), c(0), c(1), c(2), dc.norm());
    return 0;
}

}  // namespace

int main(int argc, char** argv) {
    open3d::utility::SetVerbosityLevel(open3d::utility::VerbosityLevel::Error);
    const std::string cmd = argc > 1 ? argv[1] : "";
    if (cmd == "register" && argc >= 4)
        return cmd_register(argv[2], argv[3], argc > 4 ? std::atoi(argv[4]) : 8,
                            argc > 5 ? std::atof(argv[5]) : 5.0);
    if (cmd == "icp" && argc == 20) {  // sick_fit icp MODEL SCAN m00..m33: refine() from a given pose
        auto mesh = load_mesh(argv[2]);
        auto scan = load_cloud(argv[3]);
        Samples s = sample_mesh(*mesh, 4.0, 1);
        PointCloud dense;
        dense.points_ = s.p;
        dense.normals_ = s.n;
        Fit f = refine(*scan, *dense.VoxelDownSample(1.0), parse_matrix(argv + 4));
        std::printf("icp inliers(3mm) %d fitness %.4f rmse %.3f\n  flat", f.inliers, f.fitness, f.rmse);
        for (int j = 0; j < 16; ++j) std::printf(" %.9g", f.T_scan_model(j / 4, j % 4));
        std::printf("\n");
        return 0;
    }
    if (cmd == "noplane" && argc == 5) return cmd_noplane(argv[2], argv[3], std::atof(argv[4]));
    if (cmd == "multistart" && argc == 8)
        return cmd_multistart(argv[2], argv[3], std::atoi(argv[4]),
                              Vector3d(std::atof(argv[5]), std::atof(argv[6]), std::atof(argv[7])));
    if (cmd == "eval" && argc == 20) return cmd_eval(argv[2], argv[3], parse_matrix(argv + 4));
    if (cmd == "compare" && argc == 35)
        return cmd_compare(parse_matrix(argv + 2), parse_matrix(argv + 18), argv[34]);
    std::fprintf(stderr,
                 "usage: sick_fit register MODEL SCAN [SEEDS] [VOXEL] | eval MODEL SCAN m00..m33 | "
                 "compare A00..A33 B00..B33 MODEL\n");
    return 2;
}
