#include "partloc/core/symmetry.hpp"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>

#include "partloc/core/format.hpp"
#include "partloc/core/geometry.hpp"
#include "partloc/core/icp.hpp"

namespace partloc {

namespace {

constexpr double kDeg = M_PI / 180.0;

/// Evenly spread indices of at most `count` of n samples.
std::vector<std::size_t> spread(std::size_t n, std::size_t count) {
    std::vector<std::size_t> out;
    const std::size_t m = std::min(n, std::max<std::size_t>(count, 1));
    out.reserve(m);
    for (std::size_t i = 0; i < m; ++i) out.push_back(i * n / m);
    return out;
}

/// The fraction of the samples `picks` that X maps onto the model; stops early (returning what it has, below
/// `stop_below`) once so many are off that the fraction cannot reach stop_below.
double on_fraction(const Surface& model, const std::vector<std::size_t>& picks, const Eigen::Isometry3d& X,
                   const SymmetrySettings& s, double stop_below) {
    if (picks.empty() || model.spacing <= 0) return 0.0;
    const double reach = s.reach * model.spacing, plane = s.plane * model.spacing;
    const double cos_normal = std::cos(s.normal_deg * kDeg);
    const auto allowed_off = static_cast<std::size_t>((1.0 - stop_below) * static_cast<double>(picks.size()));
    std::size_t off = 0;
    for (std::size_t i : picks) {
        const Eigen::Vector3d p = X * model.points[i];
        const Eigen::Vector3d n = X.linear() * model.normals[i];
        int idx[4];
        double d2[4];
        const int found = model.nearest(p, 4, reach, idx, d2);
        bool on = false;
        for (int k = 0; k < found && !on; ++k) {
            const Eigen::Vector3d& m = model.normals[static_cast<std::size_t>(idx[k])];
            on = m.dot(n) >= cos_normal &&
                 std::abs(m.dot(p - model.points[static_cast<std::size_t>(idx[k])])) <= plane;
        }
        if (!on && ++off > allowed_off) break;
    }
    return 1.0 - static_cast<double>(off) / static_cast<double>(picks.size());
}

/// Whether X (model frame, near a symmetry) maps the model onto itself: screened loosely (a turn about a
/// centre estimated from the samples is off by a fraction of a sampling), refined by a point-to-plane fit of
/// the turned samples onto the model, which must stay near X, and then judged strictly. The refined turn in
/// `refined`.
bool maps_onto_itself(const Surface& model, const std::vector<std::size_t>& picks, const Eigen::Isometry3d& X,
                      const SymmetrySettings& s, Eigen::Isometry3d* refined = nullptr) {
    SymmetrySettings loose = s;
    loose.reach = 4.0 * s.reach;
    loose.plane = 10.0 * s.plane;
    loose.normal_deg = 2.0 * s.normal_deg;
    const double screen = s.min_on - 0.1;
    if (on_fraction(model, picks, X, loose, screen) < screen) return false;
    std::vector<Eigen::Vector3d> source, normals;
    for (std::size_t k = 0; k < picks.size(); k += 3) {
        source.push_back(model.points[picks[k]]);
        normals.push_back(model.normals[picks[k]]);
    }
    IcpSettings is;
    is.max_distances = {loose.reach * model.spacing, s.reach * model.spacing};
    const IcpResult fit = icp_point_to_plane(source, model, X, is, &normals);
    const Eigen::Isometry3d D = fit.T_target_source * X.inverse();
    if (rotation_angle_deg(D.linear()) > 2.0 ||
        (D * model.center - model.center).norm() > 3.0 * model.spacing)
        return false;
    if (refined) *refined = fit.T_target_source;
    return on_fraction(model, picks, fit.T_target_source, s, s.min_on) >= s.min_on;
}

Eigen::Isometry3d turn_about(const Eigen::Vector3d& centre, const Eigen::Vector3d& axis, double deg) {
    return rotation_about_line(centre, axis.normalized(), deg);
}

/// Adds `a` (up to sign) unless a near-parallel axis is already there.
void add_axis(std::vector<Eigen::Vector3d>& axes, Eigen::Vector3d a) {
    if (!(a.norm() > 1e-6)) return;
    a.normalize();
    for (const auto& b : axes)
        if (std::abs(a.dot(b)) > std::cos(2.0 * kDeg)) return;
    axes.push_back(a);
}

/// The directions most of the model's normals take (up to sign): its faces' normals, for a boxy model.
std::vector<Eigen::Vector3d> dominant_normals(const Surface& model, const std::vector<std::size_t>& picks) {
    struct Cluster {
        Eigen::Vector3d sum = Eigen::Vector3d::Zero();
        std::size_t count = 0;
    };
    std::vector<Cluster> clusters;
    const double cos_join = std::cos(10.0 * kDeg);
    for (std::size_t i : picks) {
        const Eigen::Vector3d& n = model.normals[i];
        bool joined = false;
        for (auto& c : clusters) {
            const double d = c.sum.normalized().dot(n);
            if (std::abs(d) >= cos_join) {
                c.sum += d < 0 ? -n : n;
                ++c.count;
                joined = true;
                break;
            }
        }
        if (!joined && clusters.size() < 64) clusters.push_back({n, 1});
    }
    std::sort(clusters.begin(), clusters.end(),
              [](const Cluster& a, const Cluster& b) { return a.count > b.count; });
    std::vector<Eigen::Vector3d> out;
    for (const auto& c : clusters)
        if (static_cast<double>(c.count) >= 0.02 * static_cast<double>(picks.size()) && out.size() < 8)
            out.push_back(c.sum.normalized());
    return out;
}

bool same_turn(const Eigen::Isometry3d& a, const Eigen::Isometry3d& b) {
    return rotation_angle_deg(a.linear().transpose() * b.linear()) < 1.0;
}

}  // namespace

double fraction_on_itself(const Surface& model, const Eigen::Isometry3d& X,
                          const SymmetrySettings& settings) {
    return on_fraction(model, spread(model.points.size(), settings.samples), X, settings, 0.0);
}

Symmetry find_symmetry(const Surface& model, const SymmetrySettings& settings) {
    Symmetry sym;
    const std::size_t n = model.points.size();
    if (n < 20 || model.normals.size() != n || !(model.spacing > 0)) return sym;
    const std::vector<std::size_t> picks = spread(n, settings.samples);
    for (const auto& p : model.points) sym.centre += p;
    sym.centre /= static_cast<double>(n);
    Eigen::Matrix3d C = Eigen::Matrix3d::Zero();
    for (const auto& p : model.points) C += (p - sym.centre) * (p - sym.centre).transpose();
    C /= static_cast<double>(n);
    const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(C);

    // Candidate axes: a symmetry keeps the samples' centre and second moments, so it turns about a principal
    // axis, or about any axis of a principal plane (or of space) whose moments are equal; in such a plane the
    // faces' normals and their bisectors give the axes a boxy model turns about.
    std::vector<Eigen::Vector3d> axes;
    for (int k = 0; k < 3; ++k) add_axis(axes, eig.eigenvectors().col(k));
    const std::vector<Eigen::Vector3d> faces = dominant_normals(model, picks);
    for (const auto& a : faces) add_axis(axes, a);
    for (std::size_t i = 0; i < faces.size(); ++i)
        for (std::size_t j = i + 1; j < faces.size(); ++j) {
            add_axis(axes, faces[i] + faces[j]);
            add_axis(axes, faces[i] - faces[j]);
            add_axis(axes, faces[i].cross(faces[j]));
        }
    const double moment_tol = 0.05 * std::max(C.norm(), 1e-30);
    const auto keeps_moments = [&](const Eigen::Isometry3d& X) {
        return (X.linear() * C * X.linear().transpose() - C).norm() <= moment_tol;
    };
    Eigen::Isometry3d refined;
    const auto holds = [&](const Eigen::Isometry3d& X) {
        return keeps_moments(X) && maps_onto_itself(model, picks, X, settings, &refined);
    };
    const auto add_turn = [&](const Eigen::Isometry3d& X) {
        if (rotation_angle_deg(X.linear()) < 1.0) return;
        for (const auto& t : sym.turns)
            if (same_turn(t, X)) return;
        sym.turns.push_back(X);
    };

    std::vector<Eigen::Vector3d> revolutions;
    for (const auto& a : axes) {
        if (holds(turn_about(sym.centre, a, settings.free_turn_deg)) &&
            holds(turn_about(sym.centre, a, 2.3 * settings.free_turn_deg))) {
            revolutions.push_back(a);
            continue;
        }
        for (int fold = 2; fold <= settings.max_fold; ++fold)
            if (holds(turn_about(sym.centre, a, 360.0 / fold)))
                for (int k = 1; k < fold; ++k) {
                    Eigen::Isometry3d power = Eigen::Isometry3d::Identity();
                    for (int j = 0; j < k; ++j) power = refined * power;
                    add_turn(power);
                }
    }
    // Every turn keeps the centre in place: R c + t = c. The samples' mean is off it by a fraction of a
    // spacing; the least change to it that the refined turns keep in place is the centre.
    if (!sym.turns.empty()) {
        Eigen::Matrix3d A = Eigen::Matrix3d::Zero();
        Eigen::Vector3d b = Eigen::Vector3d::Zero();
        for (const auto& t : sym.turns) {
            const Eigen::Matrix3d M = Eigen::Matrix3d::Identity() - t.linear();
            A += M.transpose() * M;
            b += M.transpose() * t.translation();
        }
        const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> e(A);
        Eigen::Vector3d step = Eigen::Vector3d::Zero();
        const Eigen::Vector3d r = e.eigenvectors().transpose() * (b - A * sym.centre);
        for (int k = 0; k < 3; ++k)
            if (e.eigenvalues()[k] > 1e-6 * e.eigenvalues().maxCoeff())
                step += e.eigenvectors().col(k) * (r[k] / e.eigenvalues()[k]);
        sym.centre += step;
    }
    if (revolutions.size() >= 2) {
        sym.sphere = true;
        sym.turns.clear();
    } else if (revolutions.size() == 1) {
        sym.revolution = true;
        sym.axis = revolutions.front();
        // Spins are told by the axis; what is left is what turns the axis (end for end).
        sym.turns.erase(std::remove_if(sym.turns.begin(), sym.turns.end(),
                                       [&](const Eigen::Isometry3d& t) {
                                           return (t.linear() * sym.axis - sym.axis).norm() < 0.02;
                                       }),
                        sym.turns.end());
    }
    return sym;
}

std::vector<Eigen::Isometry3d> Symmetry::representatives() const {
    std::vector<Eigen::Isometry3d> out = turns;
    if (revolution)
        for (double deg : {90.0, 180.0}) out.push_back(turn_about(centre, axis, deg));
    if (sphere)
        for (int k = 0; k < 3; ++k) out.push_back(turn_about(centre, Eigen::Vector3d::Unit(k), 90.0));
    return out;
}

std::string Symmetry::sentence() const {
    const auto vec = [](const Eigen::Vector3d& v) {
        const Eigen::Vector3d r = (v.array().abs() < 5e-4).select(0.0, v);  // no "-0"
        return format("(%.3g, %.3g, %.3g)", r.x(), r.y(), r.z());
    };
    if (sphere) return "it maps onto itself turned any way about " + vec(centre) + " (a sphere)";
    std::string s;
    if (revolution) s = "it spins freely about the axis " + vec(axis) + " through " + vec(centre);
    // One sentence per axis: the smallest turn about it.
    std::vector<std::pair<Eigen::Vector3d, double>> told;
    for (const auto& t : turns) {
        const Eigen::AngleAxisd aa(t.linear());
        Eigen::Vector3d a = aa.axis();
        double deg = aa.angle() / kDeg;
        if (deg > 180.0 + 1e-6) deg = 360.0 - deg, a = -a;
        Eigen::Index sign_ix = 0;
        a.cwiseAbs().maxCoeff(&sign_ix);
        if (a[sign_ix] < 0) a = -a;
        bool merged = false;
        for (auto& [b, d] : told)
            if (std::abs(a.dot(b)) > std::cos(2.0 * kDeg)) {
                d = std::min(d, deg);
                merged = true;
            }
        if (!merged) told.emplace_back(a, deg);
    }
    for (std::size_t k = 0; k < told.size(); ++k) {
        s += k == 0 ? (s.empty() ? "it maps onto itself turned " : ", and maps onto itself turned ")
                    : (k + 1 == told.size() ? " and " : ", ");
        s += format("%.0f deg about ", told[k].second) + vec(told[k].first);
    }
    if (!told.empty()) s += ", through " + vec(centre);
    return s;
}

bool common_symmetry(const std::vector<PlacedSymmetry>& models, Eigen::Isometry3d* turn, std::size_t* source,
                     const SymmetrySettings& settings) {
    for (std::size_t i = 0; i < models.size(); ++i) {
        const PlacedSymmetry& m = models[i];
        if (!m.symmetry || !m.surface || !m.symmetry->any()) continue;
        std::vector<Eigen::Isometry3d> reps = m.symmetry->representatives();
        if (m.symmetry->sphere)  // two spheres leave the turns about the line through their centres
            for (std::size_t j = 0; j < models.size(); ++j) {
                if (j == i || !models[j].symmetry) continue;
                const Eigen::Vector3d other =
                    m.T_frame_model.inverse() * (models[j].T_frame_model * models[j].symmetry->centre);
                if ((other - m.symmetry->centre).norm() > 1e-9)
                    reps.push_back(turn_about(m.symmetry->centre, other - m.symmetry->centre, 90.0));
            }
        for (const auto& r : reps) {
            const Eigen::Isometry3d S = m.T_frame_model * r * m.T_frame_model.inverse();
            bool all = true;
            for (std::size_t j = 0; j < models.size() && all; ++j) {
                if (j == i) continue;
                const PlacedSymmetry& o = models[j];
                if (!o.surface) continue;
                const Eigen::Isometry3d X = o.T_frame_model.inverse() * S * o.T_frame_model;
                all = maps_onto_itself(*o.surface, spread(o.surface->points.size(), settings.samples), X,
                                       settings);
            }
            if (all) {
                if (turn) *turn = S;
                if (source) *source = i;
                return true;
            }
        }
    }
    return false;
}

}  // namespace partloc
