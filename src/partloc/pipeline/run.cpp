#include "partloc/pipeline/run.hpp"

#include <open3d/geometry/KDTreeSearchParam.h>
#include <tbb/global_control.h>
#include <tbb/parallel_for.h>
#include <tbb/task_group.h>

#include <algorithm>
#include <chrono>
#include <exception>
#include <mutex>
#include <optional>
#include <stdexcept>

#include "partloc/core/cloud_stats.hpp"
#include "partloc/core/extent.hpp"
#include "partloc/core/format.hpp"
#include "partloc/core/median.hpp"
#include "partloc/core/register_scan.hpp"
#include "partloc/core/stock.hpp"
#include "partloc/pipeline/job_checks.hpp"
#include "partloc/pipeline/machining.hpp"
#include "partloc/pipeline/part.hpp"
#include "partloc/pipeline/uncertainty.hpp"

namespace partloc {

namespace {

using Clock = std::chrono::steady_clock;
double seconds_since(Clock::time_point t0) {
    return std::chrono::duration<double>(Clock::now() - t0).count();
}

/// One scan registered by its fiducials (§3.4.1), less those `left_out` marks (none when empty), and what it
/// brings to the part.
void register_one(const Job& job, const JobPreparation& p, const Config& config, std::size_t i,
                  ScanRegistration& reg, ScanEvidence& evidence, const std::vector<char>& left_out = {}) {
    const Scan& scan = job.scans[i];
    const Scale& scale = p.scales[i];
    if (scan.points->points_.size() < config.scale.min_scan_points) {
        reg.reason = "too few valid points (" + std::to_string(scan.points->points_.size()) + ")";
        return;
    }
    // Points without depth in every direction show no fiducial, and the normals' and the hull's libraries
    // fail on them (io::check_job_geometry refuses them at load; this for a program that did not call it).
    const std::string flat = rank_problem(extent_of(scan.points->points_));
    if (!flat.empty()) {
        reg.reason = flat + ": a scan needs points spread in three dimensions";
        return;
    }
    if (scale.spacing <= 0) {
        reg.reason = "its point spacing could not be measured";
        return;
    }
    const Eigen::Vector3d viewpoint = estimate_viewpoint(*scan.points, scale.spacing);
    const PreparedScan ps = prepare_scan(*scan.points, scale, p.sampling, viewpoint);
    std::vector<PlacedFiducial> placed;
    std::vector<std::size_t> job_index;  // of each placed fiducial
    for (std::size_t k = 0; k < job.fiducials.size(); ++k) {
        if (k < left_out.size() && left_out[k]) continue;
        placed.push_back(
            {job.fiducials[k].name, &p.models[k], fiducial_at(job.machine, job.fiducials[k], scan.axes)});
        job_index.push_back(k);
    }
    if (placed.empty()) {
        reg.reason = "every fiducial is left out (moved or probed wrong)";
        return;
    }
    reg = register_scan(ps, placed, config.candidates, config.registration);
    if (placed.size() < job.fiducials.size()) {
        // Back to the job's fiducials: indices, and a fit for each one left out that says so.
        for (auto& k : reg.fiducials) k = job_index[k];
        for (auto& k : reg.moved) k = job_index[k];
        reg.source = job_index[reg.source];
        std::vector<FiducialFit> fits(job.fiducials.size());
        for (std::size_t k = 0; k < fits.size(); ++k) {
            fits[k].fiducial = job.fiducials[k].name;
            fits[k].reason = "left out: another scan found it moved or probed wrong";
        }
        for (std::size_t j = 0; j < reg.fits.size() && j < job_index.size(); ++j)
            fits[job_index[j]] = reg.fits[j];
        reg.fits = std::move(fits);
        reg.hypotheses.clear();  // their indices are the placed fiducials'
    }
    if (!reg.valid) return;
    // The scan's workpiece points, moved to the workpiece at the reference axis position (§3.4.2).
    const Eigen::Isometry3d T_machine0_scan =
        job.machine.motion(job.workpiece.moves_with, scan.axes).inverse() * reg.T_machine_scan;
    if (reg.scale == 1.0) {
        evidence = scan_evidence(*ps.cloud, scale, T_machine0_scan, ps.viewpoint, p.region, config.part);
        return;
    }
    // The scan as the scanner's fitted scale corrects it; the scanner moves with its points, so that the
    // rays keep their directions.
    const auto correct = [&](const Eigen::Vector3d& q) {
        return Eigen::Vector3d(reg.scale_centre + reg.scale * (q - reg.scale_centre));
    };
    open3d::geometry::PointCloud corrected = *ps.cloud;
    for (auto& q : corrected.points_) q = correct(q);
    evidence = scan_evidence(corrected, scale, T_machine0_scan, correct(ps.viewpoint), p.region, config.part);
}

/// Each scan's outcome, written once the part has chosen its scans.
ScanResult scan_result(const Job& job, std::size_t i, const ScanRegistration& reg, const JobPreparation& p,
                       const PartSelection* selection) {
    ScanResult r;
    r.file = job.scans[i].file;
    r.points = job.scans[i].points->points_.size();
    r.point_spacing = p.scales[i].spacing;
    r.noise = p.scales[i].noise;
    r.fits = reg.fits;
    if (selection && !selection->rejected[i].empty()) {
        r.reason = selection->rejected[i];  // taken back by the part: nothing of the registration stays
        return r;
    }
    r.valid = reg.valid;
    r.reason = reg.reason;
    r.warnings = reg.warnings;
    if (!reg.valid) return r;
    for (std::size_t k : reg.fiducials) r.fiducials.push_back(job.fiducials[k].name);
    r.T_machine_scan = reg.T_machine_scan;
    r.scale = reg.scale;
    r.scale_centre = reg.scale_centre;
    r.scale_sigma = reg.scale_sigma;
    r.score = reg.score;
    r.rmse = reg.rmse;
    r.information = reg.information;
    r.JtJ_per_fiducial = reg.JtJ_per_fiducial;
    if (selection && !selection->warnings[i].empty()) r.warnings.push_back(selection->warnings[i]);
    return r;
}

/// merged.ply's points (one per voxel of the scans' spacing) and the stock from them, in a task beside the
/// datums and the uncertainty.
class StockTask {
  public:
    StockTask(std::shared_ptr<const open3d::geometry::PointCloud> points, double spacing, bool build,
              StockSettings settings) {
        settings.spacing = spacing;
        group_.run([this, points, spacing, build, settings] {
            try {
                written_ = points->VoxelDownSample(spacing);
                if (build && spacing > 0) stock_ = build_stock(*written_, settings);
            } catch (...) {
                error_ = std::current_exception();
            }
        });
    }
    ~StockTask() { group_.wait(); }
    /// The points written to merged.ply; rethrows the task's error when they are missing.
    std::shared_ptr<open3d::geometry::PointCloud> written() {
        group_.wait();
        if (!written_ && error_) std::rethrow_exception(error_);
        return written_;
    }
    std::shared_ptr<open3d::geometry::TriangleMesh> stock() {
        group_.wait();
        if (error_) std::rethrow_exception(error_);
        return stock_;
    }

  private:
    tbb::task_group group_;
    std::shared_ptr<open3d::geometry::PointCloud> written_;
    std::shared_ptr<open3d::geometry::TriangleMesh> stock_;
    std::exception_ptr error_;
};

/// Oriented samples of a nominal model (reference surfaces or a datum) at `spacing`; null when it is empty.
std::shared_ptr<open3d::geometry::PointCloud> oriented_samples(const ModelSource& m, double spacing) {
    if (m.mesh && !m.mesh->triangles_.empty()) return sample_mesh(*m.mesh, spacing);
    if (!m.points || m.points->points_.empty()) return nullptr;
    auto samples = std::make_shared<open3d::geometry::PointCloud>(*m.points);
    if (!samples->HasNormals()) {
        samples->EstimateNormals(open3d::geometry::KDTreeSearchParamKNN(20));
        samples->OrientNormalsConsistentTangentPlane(12);
    }
    return samples;
}

/// The datums' surfaces and their fit (3-2-1), or, for a simultaneous fit, each datum's residual there.
struct DatumStage {
    std::string reason;  ///< why the part is not located; empty when it is
    std::vector<DatumSurface> surfaces;
    DatumFitSettings settings;
};

DatumStage fit_datum_hierarchy(const Job& job, const PartFit& part, double ref_spacing, const Config& config,
                               WorkpieceResult& w, Eigen::Isometry3d& T_located_nominal) {
    DatumStage d;
    if (job.workpiece.datums.empty()) return d;
    for (const auto& datum : job.workpiece.datums) {
        const auto samples = oriented_samples(datum.surfaces, ref_spacing);
        if (!samples) {
            d.reason = "datum " + datum.name + ": its surfaces are empty";
            return d;
        }
        d.surfaces.push_back({datum.name, make_surface(samples, ref_spacing)});
    }
    d.settings = config.datums;
    d.settings.noise = part.settings.noise;
    d.settings.spacing = part.settings.spacing;
    const auto& merged = part.merged->points_;
    if (job.workpiece.fit != WorkpieceFitMode::Datums) {
        w.datums = evaluate_datums(merged, d.surfaces, part.fit.T_located_nominal, d.settings);
        return d;
    }
    const DatumFit df = fit_datums(merged, d.surfaces, part.fit.T_located_nominal, d.settings);
    w.datums = df.datums;
    w.points = merged.size();
    if (!df.valid) {
        d.reason = df.reason;
        return d;
    }
    T_located_nominal = df.T_located_nominal;
    w.rmse = df.rmse;
    w.inliers = df.inliers;
    w.information = df.information / std::max(part.settings.noise * part.settings.noise, 1e-30);
    return d;
}

/// What the uncertainty's jackknife refits: what the fit took, scan by scan.
UncertaintyInputs uncertainty_inputs(const Job& job, const std::vector<ScanRegistration>& regs,
                                     std::vector<ScanEvidence>& evidence, const PartFit& part,
                                     const Config& config) {
    UncertaintyInputs ui;
    // Every point near the reference surfaces for the simultaneous fit (the part is located, so each fitted
    // scan with points has them); for the datums' fit, which takes the merged points, every k-th of each
    // scan's workpiece points (the datums need not lie on the reference surfaces).
    const bool on_reference_fit = job.workpiece.fit != WorkpieceFitMode::Datums;
    ui.scan_points_most =
        on_reference_fit ? config.uncertainty.scan_points : config.uncertainty.datum_scan_points;
    for (std::size_t i = 0; i < regs.size(); ++i) {
        if (!part.selection.registered[i] || !part.selection.in_fit[i]) continue;
        if (!on_reference_fit || !part.on_reference[i]) {
            if (evidence[i].workpiece_points) {
                std::vector<std::size_t> taken;
                const std::size_t n = evidence[i].workpiece_points->points_.size();
                for (std::size_t k = 0; k < n; k += scan_stride(n, ui.scan_points_most)) taken.push_back(k);
                evidence[i].normals_at(taken);
            }
            ui.scan_points.push_back(evidence[i].workpiece_points);
        } else {
            ui.scan_points.push_back(part.on_reference[i]);
        }
        ui.scan_fiducials.push_back(regs[i].fiducials);
        const AxisValues& q = job.scans[i].axes;
        std::vector<Eigen::Isometry3d> moved;
        for (std::size_t k : regs[i].fiducials) {
            const Fiducial& f = job.fiducials[k];
            moved.push_back(job.machine.motion(f.moves_with, q) *
                            job.machine.motion(f.moves_with, f.probed_at).inverse());
        }
        ui.scan_fiducial_motion.push_back(moved);
        ui.scan_fiducial_jtj.push_back(regs[i].JtJ_per_fiducial);
        ui.scan_to_axes0.push_back(job.machine.motion(job.workpiece.moves_with, q).inverse());
    }
    ui.fit_distance = part.fit.distance;
    ui.noise = part.settings.noise;
    return ui;
}

void check_job(const Job& job) {
    if (job.fiducials.empty()) throw std::invalid_argument("the job has no fiducials");
    for (const auto& f : job.fiducials) {
        job.machine.motion(f.moves_with, f.probed_at);  // throws on an unknown axis
        // A flat or linear model would reach Qhull (the visible surface's hull) and the pose search's tables
        // degenerate; io::check_job_geometry says so naming the file, this for a program that did not call
        // it.
        if (!f.model.mesh && !f.model.points)
            throw std::invalid_argument("fiducial " + f.name + " has no model");
        const auto& v = f.model.mesh ? f.model.mesh->vertices_ : f.model.points->points_;
        const std::string problem = rank_problem(extent_of(v));
        if (!problem.empty())
            throw std::invalid_argument("fiducial " + f.name + " (" + f.model.file + "): " + problem +
                                        "; a fiducial needs a three-dimensional shape");
    }
    job.machine.motion(job.workpiece.moves_with, {});
}

}  // namespace

JobPreparation prepare_job(const Job& job, const RunSettings& settings) {
    const ScaleSettings& cs = settings.config.scale;
    JobPreparation p;
    p.scales.resize(job.scans.size());
    tbb::parallel_for(std::size_t(0), job.scans.size(), [&](std::size_t i) {
        CloudStats m;
        if (!job.scanner.point_spacing || !job.scanner.noise)
            m = measure_cloud(*job.scans[i].points, cs.measure_points, settings.seed + i);
        Scale& s = p.scales[i];
        s.spacing = job.scanner.point_spacing.value_or(m.spacing);
        s.noise = std::max(job.scanner.noise.value_or(m.noise), cs.min_noise * s.spacing);
    });
    std::vector<double> diameters, spacings;
    for (const auto& f : job.fiducials) diameters.push_back(bounding_box(f.model).diagonal().norm());
    for (const auto& s : p.scales)
        if (s.spacing > 0) spacings.push_back(s.spacing);
    p.spacing = spacings.empty() ? 0.0 : median_of(spacings);
    const double max_spacing = spacings.empty() ? 0.0 : *std::max_element(spacings.begin(), spacings.end());
    p.sampling = std::max(cs.sampling_diameter * median_of(diameters), cs.sampling_spacings * max_spacing);
    p.models.resize(job.fiducials.size());
    tbb::parallel_for(std::size_t(0), job.fiducials.size(), [&](std::size_t k) {
        const auto& f = job.fiducials[k];
        const double dense = std::max(p.spacing, diameters[k] / cs.dense_divisions);
        const auto* mesh = f.model.mesh.get();
        const auto* points = f.model.points.get();
        p.models[k] = settings.models ? settings.models->prepare(f.name, mesh, points, dense, p.sampling)
                                      : prepare_model(f.name, mesh, points, dense, p.sampling);
    });
    p.region = workpiece_region(job, p.spacing);
    return p;
}

/// Registers every scan (in parallel; each scan's outcome depends on that scan alone), telling each one's
/// end to settings.progress.
void register_scans(const Job& job, const JobPreparation& prep, const RunSettings& settings,
                    std::vector<ScanRegistration>& regs, std::vector<ScanEvidence>& evidence,
                    std::vector<double>& seconds) {
    const std::size_t n = job.scans.size();
    std::mutex told;
    std::size_t finished = 0;
    if (settings.progress) settings.progress(format("registering %zu scans", n));
    tbb::parallel_for(std::size_t(0), n, [&](std::size_t i) {
        const auto ts = Clock::now();
        register_one(job, prep, settings.config, i, regs[i], evidence[i]);
        seconds[i] = seconds_since(ts);
        if (!settings.progress) return;
        std::string names;
        for (const std::size_t k : regs[i].fiducials)
            names += (names.empty() ? "" : ",") + job.fiducials[k].name;
        const std::lock_guard<std::mutex> lock(told);
        ++finished;
        settings.progress(
            format("scan %zu of %zu (%s, %.1f s): ", finished, n, job.scans[i].file.c_str(), seconds[i]) +
            (regs[i].valid ? "placed by fiducials " + names : "not placed: " + regs[i].reason));
    });
}

/// A fiducial that a registered scan found moved or probed wrong (the others in its view agree without it) is
/// left out of every scan: the scans it placed, and those rejected because fiducials disagreed, are
/// registered again without it (issue 27: with A probed 0.5 mm off, scans that saw A with one other fiducial
/// were rejected or placed between the two). Leaving a fiducial out costs recall, never a wrong placement.
void reregister_without_moved(const Job& job, const JobPreparation& prep, const RunSettings& settings,
                              std::vector<ScanRegistration>& regs, std::vector<ScanEvidence>& evidence,
                              std::vector<double>& seconds) {
    const std::size_t n = regs.size();
    std::vector<char> left_out(job.fiducials.size(), 0);
    std::vector<std::string> found_by(job.fiducials.size());
    for (std::size_t i = 0; i < n; ++i) {
        if (!regs[i].valid) continue;
        for (std::size_t k : regs[i].moved) {
            if (!left_out[k]) found_by[k] = job.scans[i].file;
            left_out[k] = 1;
        }
    }
    if (std::find(left_out.begin(), left_out.end(), 1) == left_out.end()) return;
    std::vector<std::size_t> again;
    for (std::size_t i = 0; i < n; ++i) {
        const ScanRegistration& r = regs[i];
        bool named_it = false, used = false;
        for (std::size_t k : r.moved) named_it |= left_out[k] != 0;
        for (std::size_t k : r.fiducials) used |= left_out[k] != 0;
        const bool disagreed = !r.valid && (r.reason.find("disagree") != std::string::npos ||
                                            r.reason.find("contradicts") != std::string::npos);
        if (!named_it && ((r.valid && used) || disagreed)) again.push_back(i);
    }
    std::string names;
    for (std::size_t k = 0; k < left_out.size(); ++k)
        if (left_out[k]) names += (names.empty() ? "" : ", ") + job.fiducials[k].name;
    if (settings.progress && !again.empty())
        settings.progress(
            format("registering %zu scans again without fiducial %s", again.size(), names.c_str()));
    tbb::parallel_for(std::size_t(0), again.size(), [&](std::size_t j) {
        const std::size_t i = again[j];
        const auto ts = Clock::now();
        regs[i] = ScanRegistration{};
        evidence[i] = ScanEvidence{};
        register_one(job, prep, settings.config, i, regs[i], evidence[i], left_out);
        seconds[i] += seconds_since(ts);
        for (std::size_t k = 0; k < left_out.size(); ++k)
            if (left_out[k])
                regs[i].warnings.push_back("fiducial " + job.fiducials[k].name + " left out of this scan: " +
                                           found_by[k] + " found it moved or probed wrong");
    });
}

/// An even subsample of at most `max_points` of the part's registered points, each with its scan and, when
/// T_located_nominal is given, its signed distance from the reference surfaces placed there (point to the
/// nearest sample's tangent plane, within `reach`): report.html's 3D view.
ViewPoints view_points(const PartFit& part, const Surface& reference,
                       const Eigen::Isometry3d* T_located_nominal, double reach, std::size_t max_points) {
    ViewPoints v;
    v.reach = reach;
    if (!part.all_registered || part.all_registered_scan.size() != part.all_registered->points_.size())
        return v;
    const auto& all = part.all_registered->points_;
    const std::size_t stride =
        std::max<std::size_t>(1, (all.size() + max_points - 1) / std::max<std::size_t>(max_points, 1));
    const Eigen::Isometry3d T_nominal_located =
        T_located_nominal ? T_located_nominal->inverse() : Eigen::Isometry3d::Identity();
    for (std::size_t i = 0; i < all.size(); i += stride) {
        if (!all[i].allFinite()) continue;
        v.points.push_back(all[i].cast<float>());
        v.scan.push_back(part.all_registered_scan[i]);
        float d = std::numeric_limits<float>::quiet_NaN();
        if (T_located_nominal) {
            const Eigen::Vector3d q = T_nominal_located * all[i];
            double d2 = 0.0;
            const int k = reference.nearest(q, &d2, reach);
            if (k >= 0) d = static_cast<float>(reference.normals[k].dot(q - reference.points[k]));
        }
        v.deviation.push_back(d);
    }
    return v;
}

JobResult run_job(const Job& job, const RunSettings& settings) {
    const auto t0 = Clock::now();
    std::optional<tbb::global_control> threads;
    if (settings.threads > 0) threads.emplace(tbb::global_control::max_allowed_parallelism, settings.threads);
    check_job(job);
    const Config& config = settings.config;
    JobResult result;
    result.units = job.units;
    WorkpieceResult& w = result.workpiece;
    std::vector<std::string> checks;  // the job's own checks' warnings
    w.T_machine_workpiece_nominal = job.workpiece.T_machine_workpiece;
    w.fit = job.workpiece.fit == WorkpieceFitMode::Datums ? "datums" : "simultaneous";
    const auto done = [&](std::string reason) {
        w.reason = std::move(reason);
        result.warnings = job.warnings;  // what reading the files found, the job's checks, then each scan's
        result.warnings.insert(result.warnings.end(), checks.begin(), checks.end());
        for (const ScanResult& r : result.scans)
            for (const std::string& warning : r.warnings) result.warnings.push_back(r.file + ": " + warning);
        for (const std::string& warning : result.machining.warnings) result.warnings.push_back(warning);
        result.seconds = seconds_since(t0);
        return std::move(result);
    };

    const auto tell = [&](const std::string& what) {
        if (settings.progress) settings.progress(what);
    };

    // Prepare: each scan's scale, the global fit's sampling, the fiducials' models, the workpiece's region.
    tell(format("preparing %zu fiducial models and measuring %zu scans", job.fiducials.size(),
                job.scans.size()));
    const JobPreparation prep = prepare_job(job, settings);
    // Scans whose size does not fit the fiducials' in the job's units (pipeline/job_checks.hpp).
    {
        // The spacing measured on each scan; a spacing the job gives says nothing of the scans' units.
        std::vector<double> spacings;
        for (const Scale& s : prep.scales) spacings.push_back(job.scanner.point_spacing ? 0.0 : s.spacing);
        checks = unit_warnings(job, summarise_scans(job, &spacings));
    }
    for (std::string& s : symmetry_warnings(job, prep.models)) checks.push_back(std::move(s));

    // Register the scans (§3.4.1, in parallel; each scan's outcome depends on that scan alone).
    const std::size_t n = job.scans.size();
    std::vector<ScanRegistration> regs(n);
    std::vector<ScanEvidence> evidence(n);
    std::vector<double> seconds(n, 0.0);
    register_scans(job, prep, settings, regs, evidence, seconds);
    reregister_without_moved(job, prep, settings, regs, evidence, seconds);
    tell("locating the part");

    // Locate the part (§3.4.2): choose the scans, merge them, fit the reference surfaces.
    PartInputs in;
    in.registrations = &regs;
    in.evidence = &evidence;
    for (const auto& f : job.fiducials) in.fiducial_names.push_back(f.name);
    in.spacing = prep.spacing;
    PartSelection selection = first_selection(in);
    const auto write_scans = [&](const PartSelection* s) {
        for (std::size_t i = 0; i < n; ++i) {
            result.scans.push_back(scan_result(job, i, regs[i], prep, s));
            result.scans.back().seconds = seconds[i];
        }
    };
    if (!selection.none_left.empty()) {
        write_scans(&selection);
        return done(selection.none_left);
    }
    const double ref_spacing =
        std::max(prep.spacing, bounding_box(job.workpiece.reference_surfaces).diagonal().norm() /
                                   config.scale.reference_divisions);
    const auto ref_samples = oriented_samples(job.workpiece.reference_surfaces, ref_spacing);
    if (!ref_samples) {
        write_scans(&selection);
        return done("the reference surfaces are empty");
    }
    const Surface reference = make_surface(ref_samples, ref_spacing);
    in.reference = &reference;
    for (std::size_t i = 0; i < n; ++i)
        in.part_at_scan.push_back(job.machine.motion(job.workpiece.moves_with, job.scans[i].axes) *
                                  reference.center);
    const PartSelection chosen = selection;
    PartFit part = fit_part(in, std::move(selection), config);
    // Scans whose part lies turned about a rotary axis from the located part: their axis values are not the
    // job's (pipeline/job_checks.hpp). Left out, and the part fitted again without them, until none is found:
    // turned scans in the fit pull the part towards them and can hide each other (seed 8, axes left out: one
    // found at first, a second only once the first was out).
    PartSelection again = chosen;
    for (std::size_t round = 0; part.fit.valid && round < n; ++round) {
        std::vector<const Eigen::Isometry3d*> placed(n, nullptr);
        for (std::size_t i = 0; i < n; ++i)
            if (part.selection.registered[i]) placed[i] = &regs[i].T_machine_scan;
        const std::vector<TurnedScan> turned =
            turned_scans(job, placed, reference, part.fit.T_located_nominal, part.settings.noise);
        if (turned.empty()) break;
        for (const TurnedScan& t : turned) {
            again.registered[t.scan] = 0;
            again.rejected[t.scan] = t.sentence();
            checks.push_back(job.scans[t.scan].file + ": " + t.sentence());
        }
        tell("locating the part again without the turned scans");
        part = fit_part(in, again, config);
    }
    // Scans in the fit that show the part elsewhere than the part located from them all (pipeline/part.hpp,
    // scans_off_part): the most-off one left out and the part fitted again while the rest outnumber those
    // off; where they do not, the scans do not show one part and nothing says which is right.
    for (std::size_t round = 0; part.fit.valid && round < n; ++round) {
        const std::vector<ScanOffPart> off = scans_off_part(part, in, config.part);
        if (off.empty()) break;
        std::size_t in_fit = 0;
        for (std::size_t i = 0; i < n; ++i)
            in_fit += part.selection.registered[i] && part.selection.in_fit[i];
        if (2 * off.size() >= in_fit) {
            std::string which;
            for (const ScanOffPart& o : off)
                which += (which.empty() ? "" : ", ") + job.scans[o.scan].file + format(" by %.3g", o.moved);
            write_scans(&part.selection);
            return done(
                format("the scans do not show one part: fitted on its own points, the part lies off the part "
                       "located from them all (%s %s, where %.3g is the noise): did the part move in its "
                       "clamp between scans, or are scans at other axis positions given without their axes?",
                       which.c_str(), job.units.c_str(), part.settings.noise));
        }
        const ScanOffPart& worst = off.front();
        const std::string why = format(
            "fitted on its own points, the part lies %.3g %s off the part the other scans locate: did the "
            "part move in its clamp, or are its axis values not the job's? Left out of the part",
            worst.moved, job.units.c_str());
        again.registered[worst.scan] = 0;
        again.rejected[worst.scan] = why;
        checks.push_back(job.scans[worst.scan].file + ": " + why);
        tell("locating the part again without a scan that shows it elsewhere");
        part = fit_part(in, again, config);
    }
    write_scans(&part.selection);
    if (!part.selection.none_left.empty()) return done(part.reason);
    w.rmse = part.fit.rmse;
    w.points = part.fit_points;
    w.inliers = part.fit.inliers;
    w.information = part.fit.JtJ / std::max(part.settings.noise * part.settings.noise, 1e-30);
    const double view_reach = 3.0 * std::max(part.settings.noise, prep.spacing) + 3.0 * ref_spacing;
    if (!part.valid) {
        result.view = view_points(part, reference, nullptr, view_reach, config.report.view_points);
        result.merged = part.all_registered->VoxelDownSample(prep.spacing);
        return done(part.reason);
    }
    StockTask stock(part.all_registered, prep.spacing, settings.build_stock, config.stock);
    Eigen::Isometry3d T_located_nominal = part.fit.T_located_nominal;
    const DatumStage datums = fit_datum_hierarchy(job, part, ref_spacing, config, w, T_located_nominal);
    if (!datums.reason.empty()) {
        result.merged = stock.written();
        return done(datums.reason);
    }
    // The points scatter less about the fitted surfaces than the scanner's noise: its noise is along its
    // rays, and a surface seen at an angle shows only part of it along its normal. The information is that
    // of the points the fit used, so it takes their scatter.
    const double noise = part.settings.noise;
    if (w.rmse > 0 && w.rmse < noise) w.information *= (noise * noise) / (w.rmse * w.rmse);
    w.valid = true;
    w.T_machine_workpiece = T_located_nominal * job.workpiece.T_machine_workpiece;

    // Estimate the uncertainty (pipeline/uncertainty.hpp).
    tell("estimating the uncertainty");
    UncertaintyInputs ui = uncertainty_inputs(job, regs, evidence, part, config);
    ui.reference = &reference;
    ui.T_located_nominal = T_located_nominal;
    ui.information = w.information;
    if (job.workpiece.fit == WorkpieceFitMode::Datums)
        ui.refit = [&](const std::vector<Eigen::Vector3d>& pts,
                       const std::vector<Eigen::Vector3d>*) -> std::optional<Eigen::Isometry3d> {
            const DatumFit df = fit_datums(pts, datums.surfaces, T_located_nominal, datums.settings);
            if (!df.valid) return std::nullopt;
            return df.T_located_nominal;
        };
    estimate_uncertainty(job, ui, w);

    // Reference surfaces that the scans show elsewhere, parallel to them (pipeline/job_checks.hpp).
    if (part.all_registered && part.all_registered->HasNormals())
        for (const std::string& s :
             reference_offset_warnings(part.all_registered->points_, part.all_registered->normals_, reference,
                                       T_located_nominal, noise, prep.spacing, job.units))
            checks.push_back("workpiece.reference_surfaces: " + s);
    // Build the outputs: the final part moved by the located pose, merged.ply's points and the stock.
    tell("building the outputs");
    result.view = view_points(part, reference, &T_located_nominal, view_reach, config.report.view_points);
    if (job.workpiece.final_part && job.workpiece.final_part->mesh) {
        auto located = std::make_shared<open3d::geometry::TriangleMesh>(*job.workpiece.final_part->mesh);
        located->Transform(T_located_nominal.matrix());
        result.final_part_located = located;
    }
    result.merged = stock.written();
    // What the machinist needs to cut: the final part's allowance in the material the scans show, and its
    // placement (pipeline/machining.hpp), while the stock's mesh is built.
    if (job.workpiece.final_part) {
        tell("measuring the allowance" +
             std::string(job.workpiece.placement.maxmin ? " and placing the part" : ""));
        result.machining = plan_machining(job, *result.merged, T_located_nominal, w.T_machine_workpiece,
                                          prep.spacing, noise, config.machining);
    }
    result.stock = stock.stock();
    return done("");
}

}  // namespace partloc
