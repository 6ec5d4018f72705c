// PCL's classes as the paper names them (§3.4): SampleConsensusInitialAlignment on FPFH features, then ICP;
// MovingLeastSquares, VoxelGrid and ICP for the part. OpenMP variants of the normal and FPFH estimators
// compute the same values as the serial ones, faster on two cores.
#include "paper_pcl.hpp"

#include <pcl/features/fpfh_omp.h>
#include <pcl/features/normal_3d_omp.h>
#include <pcl/filters/voxel_grid.h>
#include <pcl/kdtree/kdtree_flann.h>
#include <pcl/point_cloud.h>
#include <pcl/point_types.h>
#include <pcl/registration/ia_ransac.h>
#include <pcl/registration/icp.h>
#include <pcl/search/kdtree.h>
#include <pcl/surface/mls.h>

#include <cmath>
#include <cstdlib>
#include <thread>

namespace partloc::bench::paper {

namespace {

using Cloud = pcl::PointCloud<pcl::PointXYZ>;
using NormalCloud = pcl::PointCloud<pcl::Normal>;
using PNCloud = pcl::PointCloud<pcl::PointNormal>;
using Features = pcl::PointCloud<pcl::FPFHSignature33>;

unsigned threads_of(int t) {
    return t > 0 ? static_cast<unsigned>(t) : std::max(1u, std::thread::hardware_concurrency());
}

Cloud::Ptr to_cloud(const Points& pts) {
    Cloud::Ptr c(new Cloud);
    c->points.reserve(pts.size());
    for (const auto& p : pts) c->points.emplace_back(p[0], p[1], p[2]);
    c->width = static_cast<std::uint32_t>(c->points.size());
    c->height = 1;
    return c;
}

Cloud::Ptr voxel_grid(const Cloud::ConstPtr& in, double leaf) {
    Cloud::Ptr out(new Cloud);
    pcl::VoxelGrid<pcl::PointXYZ> vg;
    vg.setInputCloud(in);
    const float l = static_cast<float>(leaf);
    vg.setLeafSize(l, l, l);
    vg.filter(*out);
    return out;
}

bool finite(const pcl::Normal& n) {
    return std::isfinite(n.normal_x) && std::isfinite(n.normal_y) && std::isfinite(n.normal_z);
}

/// Points with normals estimated within `radius` on `surface`, facing the viewpoint (the scanner at the scan
/// origin); points whose normal cannot be estimated are dropped.
void normals_on(const Cloud::ConstPtr& points, const Cloud::ConstPtr& surface, double radius,
                unsigned threads, Cloud::Ptr& kept, NormalCloud::Ptr& normals) {
    NormalCloud all;
    pcl::NormalEstimationOMP<pcl::PointXYZ, pcl::Normal> ne(threads);
    ne.setInputCloud(points);
    ne.setSearchSurface(surface);
    ne.setRadiusSearch(radius);
    ne.setViewPoint(0.0f, 0.0f, 0.0f);
    ne.compute(all);
    kept.reset(new Cloud);
    normals.reset(new NormalCloud);
    for (std::size_t i = 0; i < all.size(); ++i) {
        if (!finite(all[i])) continue;
        kept->push_back((*points)[i]);
        normals->push_back(all[i]);
    }
}

Features::Ptr fpfh(const Cloud::ConstPtr& points, const NormalCloud::ConstPtr& normals, double radius,
                   unsigned threads) {
    Features::Ptr f(new Features);
    pcl::FPFHEstimationOMP<pcl::PointXYZ, pcl::Normal, pcl::FPFHSignature33> est(threads);
    est.setInputCloud(points);
    est.setInputNormals(normals);
    est.setRadiusSearch(radius);
    est.compute(*f);
    return f;
}

PNCloud::Ptr with_normals(const Cloud& p, const NormalCloud& n) {
    PNCloud::Ptr out(new PNCloud);
    pcl::concatenateFields(p, n, *out);
    return out;
}

Matrix4 to_array(const Eigen::Matrix4f& m) {
    Matrix4 a{};
    for (int r = 0; r < 4; ++r)
        for (int c = 0; c < 4; ++c) a[4 * r + c] = m(r, c);
    return a;
}

struct Model {
    Cloud::Ptr down;
    Features::Ptr features;
    PNCloud::Ptr full;  ///< the 0.5 mm Poisson-disk points with their outward normals: ICP's source
};

Model prepare_model(const Points& pts, const Normals& nrm, const ProcessorParams& p, unsigned threads) {
    Model m;
    const Cloud::Ptr full = to_cloud(pts);
    NormalCloud::Ptr full_normals(new NormalCloud);
    for (const auto& n : nrm) full_normals->push_back(pcl::Normal(n[0], n[1], n[2]));
    m.full = with_normals(*full, *full_normals);
    // The model's normals are the mesh's (outward); a downsampled point takes its nearest sample's normal.
    m.down = voxel_grid(full, p.model_voxel);
    pcl::KdTreeFLANN<pcl::PointXYZ> tree;
    tree.setInputCloud(full);
    NormalCloud::Ptr down_normals(new NormalCloud);
    std::vector<int> idx(1);
    std::vector<float> d2(1);
    for (const auto& q : m.down->points) {
        tree.nearestKSearch(q, 1, idx, d2);
        down_normals->push_back((*full_normals)[idx[0]]);
    }
    m.features = fpfh(m.down, down_normals, p.model_fpfh_radius, threads);
    return m;
}

}  // namespace

std::vector<FiducialFit> fit_fiducials(const Points& scan, const std::vector<Points>& models,
                                       const std::vector<Normals>& model_normals, const ProcessorParams& p) {
    const unsigned threads = threads_of(p.threads);
    const Cloud::Ptr full = to_cloud(scan);

    // Scan features: the voxel grid, normals from the full-resolution surface, FPFH.
    Cloud::Ptr down, down_kept;
    NormalCloud::Ptr down_normals;
    down = voxel_grid(full, p.scan_voxel);
    normals_on(down, full, p.normal_radius, threads, down_kept, down_normals);
    const Features::Ptr scan_features = fpfh(down_kept, down_normals, p.scan_fpfh_radius, threads);

    // ICP's target: the full scan with its normals, one search tree for every fiducial.
    Cloud::Ptr full_kept;
    NormalCloud::Ptr full_normals;
    normals_on(full, full, p.normal_radius, threads, full_kept, full_normals);
    const PNCloud::Ptr target = with_normals(*full_kept, *full_normals);
    pcl::search::KdTree<pcl::PointNormal>::Ptr target_tree(new pcl::search::KdTree<pcl::PointNormal>);
    target_tree->setInputCloud(target);

    std::vector<FiducialFit> fits(models.size());
    for (std::size_t k = 0; k < models.size(); ++k) {
        const Model m = prepare_model(models[k], model_normals[k], p, threads);
        if (m.down->empty() || down_kept->empty()) continue;

        std::srand(static_cast<unsigned>(p.seed + k));
        pcl::SampleConsensusInitialAlignment<pcl::PointXYZ, pcl::PointXYZ, pcl::FPFHSignature33> sac;
        sac.setInputSource(m.down);
        sac.setSourceFeatures(m.features);
        sac.setInputTarget(down_kept);
        sac.setTargetFeatures(scan_features);
        sac.setNumberOfSamples(p.sac_samples);
        sac.setCorrespondenceRandomness(p.sac_randomness);
        sac.setMaximumIterations(p.sac_iterations);
        sac.setMaxCorrespondenceDistance(p.sac_max_distance);
        Cloud coarse;
        sac.align(coarse);
        fits[k].sac_score = sac.getFitnessScore();

        pcl::IterativeClosestPointWithNormals<pcl::PointNormal, pcl::PointNormal> icp;
        icp.setInputSource(m.full);
        icp.setInputTarget(target);
        icp.setSearchMethodTarget(target_tree, true);
        icp.setMaximumIterations(p.icp_iterations);
        icp.setMaxCorrespondenceDistance(p.icp_max_distance);
        icp.setTransformationEpsilon(p.icp_transformation_epsilon);
        icp.setEuclideanFitnessEpsilon(p.icp_fitness_epsilon);
        PNCloud fine;
        icp.align(fine, sac.getFinalTransformation());
        fits[k].converged = icp.hasConverged();
        fits[k].T_scan_model = to_array(icp.getFinalTransformation());

        // Metric (1): the model points and their ICP correspondences in the scan (within ICP's distance).
        std::vector<int> idx(1);
        std::vector<float> d2(1);
        double sum = 0.0;
        std::size_t n = 0;
        const double max2 = p.icp_max_distance * p.icp_max_distance;
        for (const auto& q : fine.points) {
            if (target_tree->nearestKSearch(q, 1, idx, d2) < 1 || d2[0] > max2) continue;
            sum += d2[0];
            ++n;
        }
        fits[k].correspondences = n;
        fits[k].metric = n > 0 && sum > 0 ? n / sum : 0.0;
    }
    return fits;
}

PartFit fit_part(const Points& merged, const Points& reference, const PartParams& p) {
    PartFit out;
    const Cloud::Ptr data = to_cloud(merged);
    Cloud::Ptr smooth(new Cloud);
    pcl::MovingLeastSquares<pcl::PointXYZ, pcl::PointXYZ> mls;
    pcl::search::KdTree<pcl::PointXYZ>::Ptr tree(new pcl::search::KdTree<pcl::PointXYZ>);
    mls.setInputCloud(data);
    mls.setSearchMethod(tree);
    mls.setSearchRadius(p.mls_radius);
    mls.setPolynomialOrder(p.mls_order);
    mls.setSqrGaussParam(p.mls_sqr_gauss);
    mls.setComputeNormals(false);
    mls.setNumberOfThreads(threads_of(p.threads));
    mls.process(*smooth);
    const Cloud::Ptr thin = voxel_grid(smooth, p.voxel);
    out.points = thin->size();
    if (thin->empty()) return out;

    pcl::IterativeClosestPoint<pcl::PointXYZ, pcl::PointXYZ> icp;
    icp.setInputSource(to_cloud(reference));
    icp.setInputTarget(thin);
    icp.setMaximumIterations(p.icp_iterations);
    icp.setMaxCorrespondenceDistance(p.icp_max_distance);
    icp.setTransformationEpsilon(p.icp_transformation_epsilon);
    icp.setEuclideanFitnessEpsilon(p.icp_fitness_epsilon);
    Cloud aligned;
    icp.align(aligned);
    out.converged = icp.hasConverged();
    out.T_data_nominal = to_array(icp.getFinalTransformation());
    out.fitness = icp.getFitnessScore(p.icp_max_distance);
    return out;
}

}  // namespace partloc::bench::paper
