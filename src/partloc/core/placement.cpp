#include "partloc/core/placement.hpp"

#include <glpk.h>

#include <algorithm>
#include <cmath>
#include <memory>
#include <numeric>
#include <vector>

namespace partloc {

namespace {

constexpr double kPi = 3.14159265358979323846;

/// One linear programme: columns 1-6 the move (v' in the datum axes, w' = the rotation in the datum axes
/// times `lever`), column 7 the least allowance s. GLPK keeps the basis between solves as rows are added.
class MoveProgramme {
  public:
    MoveProgramme() : lp_(glp_create_prob(), glp_delete_prob) {
        glp_set_obj_dir(lp_.get(), GLP_MAX);
        glp_add_cols(lp_.get(), 7);
        glp_set_col_bnds(lp_.get(), 7, GLP_FR, 0.0, 0.0);
        glp_set_obj_coef(lp_.get(), 7, 1.0);
    }
    void bound(int column, bool free, double half_width) {
        if (free && half_width > 0)
            glp_set_col_bnds(lp_.get(), column + 1, GLP_DB, -half_width, half_width);
        else
            glp_set_col_bnds(lp_.get(), column + 1, GLP_FX, 0.0, 0.0);
    }
    /// s - g . x <= upper
    void add_allowance_row(const Eigen::Matrix<double, 6, 1>& g, double upper) {
        int ind[8];
        double val[8];
        for (int j = 0; j < 6; ++j) {
            ind[j + 1] = j + 1;
            val[j + 1] = -g[j];
        }
        ind[7] = 7;
        val[7] = 1.0;
        add_row(7, ind, val, upper);
    }
    /// c . x <= upper
    void add_cut(const Eigen::Matrix<double, 6, 1>& c, double upper) {
        int ind[7];
        double val[7];
        for (int j = 0; j < 6; ++j) {
            ind[j + 1] = j + 1;
            val[j + 1] = c[j];
        }
        add_row(6, ind, val, upper);
    }
    bool solve() {
        glp_smcp parm;
        glp_init_smcp(&parm);
        parm.msg_lev = GLP_MSG_OFF;
        if (glp_simplex(lp_.get(), &parm) != 0) {
            // A basis made singular by the rows added: start again from the standard one.
            glp_std_basis(lp_.get());
            if (glp_simplex(lp_.get(), &parm) != 0) return false;
        }
        return glp_get_status(lp_.get()) == GLP_OPT;
    }
    Eigen::Matrix<double, 6, 1> move() const {
        Eigen::Matrix<double, 6, 1> x;
        for (int j = 0; j < 6; ++j) x[j] = glp_get_col_prim(lp_.get(), j + 1);
        return x;
    }
    double least() const { return glp_get_col_prim(lp_.get(), 7); }

  private:
    void add_row(int len, const int* ind, const double* val, double upper) {
        const int row = glp_add_rows(lp_.get(), 1);
        glp_set_row_bnds(lp_.get(), row, GLP_UP, 0.0, upper);
        glp_set_mat_row(lp_.get(), row, len, ind, val);
    }
    std::unique_ptr<glp_prob, void (*)(glp_prob*)> lp_;
};

double least_allowance(const AllowanceMap& map) { return map.all.min; }

Eigen::Vector3d rotation_vector(const Eigen::Matrix3d& R) {
    const Eigen::AngleAxisd aa(R);
    return aa.angle() * aa.axis();
}

}  // namespace

Placement place_maxmin(const PartSamples& part, const Eigen::Isometry3d& T_located,
                       const Eigen::Isometry3d& T_machine_datum, const ScannedStock& stock,
                       const AllowanceSettings& allowance, const PlacementSettings& settings,
                       const AllowanceMap& located) {
    glp_term_out(GLP_OFF);
    Placement out;
    out.map = located;
    if (std::isnan(least_allowance(located))) {
        out.reason = "no scan saw the stock around the final part";
        return out;
    }
    const Eigen::Matrix3d Rd = T_machine_datum.linear();
    const Eigen::Vector3d origin = T_machine_datum.translation();
    Eigen::AlignedBox3d box;
    for (const auto& p : located.points) box.extend(p);
    const double diagonal = box.diagonal().norm();
    const double lever = std::max(0.5 * diagonal, 1e-300);  // rotations scaled to lengths at the part's size
    const double noise = allowance.noise;
    const double still = settings.tolerance * noise;
    const double first_t = settings.step_translation > 0 ? settings.step_translation : 0.02 * diagonal;
    const double first_r = settings.step_rotation_deg * kPi / 180.0;
    const double max_t = settings.max_translation;
    const double max_r = settings.max_rotation_deg * kPi / 180.0;
    std::vector<Eigen::Vector3d> cuts_t, cuts_r;  // directions (machine frame) where the move met its limits

    AllowanceMap planes = located;  // the planes the iterations move against
    AllowanceMap current = located;
    Eigen::Isometry3d T_move = Eigen::Isometry3d::Identity();
    double tau_t = first_t, tau_r = first_r;
    bool measured = true;  // `current` was measured from the scan points (not moved on planes since)
    const std::size_t n = part.points.size();
    std::vector<double> slack(n);
    std::vector<std::size_t> order(n);
    std::vector<Eigen::Matrix<double, 6, 1>> g(n);
    while (out.iterations < settings.max_iterations) {
        // The allowance's gradient per sample in the move (datum axes; rotation times `lever`).
        const Eigen::Vector3d o = T_move * origin;
        for (std::size_t i = 0; i < n; ++i) {
            const double a = current.allowance[i];
            if (std::isnan(a)) continue;
            const Eigen::Vector3d& m = planes.planes[i].normal;
            const Eigen::Vector3d& nn = current.normals[i];
            const double along = nn.dot(m);
            const Eigen::Vector3d r = current.points[i] - o;
            const Eigen::Vector3d gv = -m / along;
            const Eigen::Vector3d gw = -(r.cross(m) + a * nn.cross(m)) / along;
            g[i].head<3>() = Rd.transpose() * gv;
            g[i].tail<3>() = Rd.transpose() * gw / lever;
        }
        const Eigen::Vector3d v_total = T_move * origin - origin;
        const Eigen::Vector3d w_total = rotation_vector(T_move.linear());

        MoveProgramme lp;
        for (int j = 0; j < 3; ++j) {
            lp.bound(j, settings.free[j], std::min(tau_t, max_t));
            lp.bound(3 + j, settings.free[3 + j], std::min(tau_r, max_r) * lever);
        }
        const auto add_cuts = [&](const std::vector<Eigen::Vector3d>& dirs, bool rotation, std::size_t from) {
            for (std::size_t k = from; k < dirs.size(); ++k) {
                Eigen::Matrix<double, 6, 1> c = Eigen::Matrix<double, 6, 1>::Zero();
                if (rotation) {
                    c.tail<3>() = Rd.transpose() * dirs[k] / lever;
                    lp.add_cut(c, max_r * (1 - 1e-6) - dirs[k].dot(w_total));
                } else {
                    c.head<3>() = Rd.transpose() * dirs[k];
                    lp.add_cut(c, max_t * (1 - 1e-9) - dirs[k].dot(v_total));
                }
            }
        };
        add_cuts(cuts_t, false, 0);
        add_cuts(cuts_r, true, 0);
        // The samples that bind: the least allowances first, then those the solution violates.
        std::iota(order.begin(), order.end(), 0);
        const auto valid_end = std::partition(
            order.begin(), order.end(), [&](std::size_t i) { return !std::isnan(current.allowance[i]); });
        const std::size_t valid = static_cast<std::size_t>(valid_end - order.begin());
        const std::size_t first = std::min<std::size_t>(valid, settings.rows_per_round);
        std::partial_sort(order.begin(), order.begin() + first, valid_end, [&](std::size_t x, std::size_t y) {
            return current.allowance[x] < current.allowance[y];
        });
        std::vector<char> in(n, 0);
        for (std::size_t k = 0; k < first; ++k) {
            lp.add_allowance_row(g[order[k]], current.allowance[order[k]] - settings.required);
            in[order[k]] = 1;
        }
        bool solved = false;
        Eigen::Matrix<double, 6, 1> x;
        for (int round = 0; round < 200; ++round) {
            ++out.iterations;
            if (!lp.solve()) break;
            x = lp.move();
            const double s = lp.least();
            std::vector<std::pair<double, std::size_t>> violated;
            for (std::size_t k = 0; k < valid; ++k) {
                const std::size_t i = order[k];
                if (in[i]) continue;
                const double v = current.allowance[i] - settings.required + g[i].dot(x) - s;
                if (v < -1e-9 * std::max(noise, 1e-300)) violated.emplace_back(v, i);
            }
            const Eigen::Vector3d vt = v_total + Rd * x.head<3>();
            const Eigen::Vector3d wt = w_total + Rd * x.tail<3>() / lever;
            bool cut = false;
            if (std::isfinite(max_t) && vt.norm() > max_t) {
                cuts_t.push_back(vt.normalized());
                add_cuts(cuts_t, false, cuts_t.size() - 1);
                cut = true;
            }
            if (std::isfinite(max_r) && wt.norm() > max_r) {
                cuts_r.push_back(wt.normalized());
                add_cuts(cuts_r, true, cuts_r.size() - 1);
                cut = true;
            }
            if (violated.empty() && !cut) {
                solved = true;
                break;
            }
            const std::size_t take = std::min<std::size_t>(violated.size(), settings.rows_per_round);
            std::partial_sort(violated.begin(), violated.begin() + take, violated.end());
            for (std::size_t k = 0; k < take; ++k) {
                const std::size_t i = violated[k].second;
                lp.add_allowance_row(g[i], current.allowance[i] - settings.required);
                in[i] = 1;
            }
        }
        if (!solved) {
            out.reason = "the placement's linear programme could not be solved";
            return out;
        }
        // The step: v moves the datum origin, w turns the part about it.
        const Eigen::Vector3d v = Rd * x.head<3>();
        const Eigen::Vector3d w = Rd * x.tail<3>() / lever;
        Eigen::Isometry3d step = Eigen::Isometry3d::Identity();
        if (w.norm() > 0) step.linear() = Eigen::AngleAxisd(w.norm(), w.normalized()).toRotationMatrix();
        step.translation() = o + v - step.linear() * o;
        const Eigen::Isometry3d T_next = step * T_move;
        const AllowanceMap next = allowance_on_planes(part, T_next * T_located, planes);
        const double moved = v.norm() + w.norm() * lever * 2.0;
        bool settled = false;
        if (least_allowance(next) > least_allowance(current) + 1e-12 * std::max(noise, 1e-300)) {
            T_move = T_next;
            current = next;
            measured = false;
            settled = moved < still;
        } else {
            tau_t *= 0.5;
            tau_r *= 0.5;
            settled = tau_t < still && tau_r * lever < still;
        }
        if (!settled) continue;
        // Settled against these planes: measure the allowance from the scan points where the part is now.
        if (out.measurements >= settings.max_measurements) break;
        AllowanceMap map = measure_allowance(part, T_move * T_located, stock, allowance);
        ++out.measurements;
        const double predicted = least_allowance(current);
        planes = map;
        current = std::move(map);
        measured = true;
        tau_t = first_t;
        tau_r = first_r;
        if (std::abs(least_allowance(current) - predicted) <= 0.1 * noise) break;
    }
    // The map at the placement, always measured from the scan points.
    if (!measured) {
        current = measure_allowance(part, T_move * T_located, stock, allowance);
        ++out.measurements;
    }
    // Never worse than where the part was located: the measured map decides.
    if (!(least_allowance(current) >= least_allowance(located))) {
        T_move = Eigen::Isometry3d::Identity();
        current = located;
    }
    out.valid = true;
    out.T_move = T_move;
    out.map = std::move(current);
    out.translation = (T_move * origin - origin).norm();
    out.rotation_deg = Eigen::AngleAxisd(T_move.linear()).angle() * 180.0 / kPi;
    out.fits = least_allowance(out.map) >= settings.required;
    return out;
}

}  // namespace partloc
