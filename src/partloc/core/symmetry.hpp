#pragma once
// A model's self-symmetries (issue 25, item 4): the rigid turns that map what a scanner can see of it onto
// itself. A fiducial with one cannot place a scan alone: every turn of it explains the scan as well, and
// each puts the scanner elsewhere. Found once, when the model is prepared; the registration asks whether
// the fiducials that place a scan share one (common_symmetry).
#include <Eigen/Geometry>
#include <string>
#include <vector>

#include "partloc/core/surface.hpp"

namespace partloc {

struct SymmetrySettings {
    std::size_t samples = 3000;  ///< of the model's samples, evenly spread, are turned and looked up
    /// A turned sample lies on the model when one of its 4 nearest samples within `reach` spacings has a
    /// normal within `normal_deg` and its tangent plane lies within `plane` spacings of the turned sample.
    double reach = 1.5, plane = 0.2, normal_deg = 20.0;
    /// A turn is a symmetry when at least this fraction of the turned samples lie on the model: 1.000
    /// measured on a box's half turns and a cylinder's spin, 0.979 on a block stepped alike at both ends but
    /// for a 1 mm step 3 mm wide at one (tests/test_symmetry.cpp), which is not called symmetric.
    double min_on = 0.985;
    /// Turns by 360/n deg, n = 2..max_fold, about each candidate axis; a turn by an angle no n divides
    /// (`free_turn_deg`) that is a symmetry too makes the axis one of revolution.
    int max_fold = 6;
    double free_turn_deg = 37.0;
};

/// The symmetries found; all in the model's frame, about `centre` (the samples' mean, which every
/// symmetry keeps in place).
struct Symmetry {
    Eigen::Vector3d centre = Eigen::Vector3d::Zero();
    /// Discrete turns (not the identity), each about `centre`.
    std::vector<Eigen::Isometry3d> turns;
    /// A body of revolution: spins by any angle about `axis` through `centre` (and `turns` holds those
    /// found besides, such as a cylinder's flip end for end).
    bool revolution = false;
    Eigen::Vector3d axis = Eigen::Vector3d::UnitZ();
    /// Every turn about `centre` (a sphere).
    bool sphere = false;

    bool any() const { return sphere || revolution || !turns.empty(); }
    /// Turns that stand for the whole set in a search for a common one: the discrete turns, a quarter and a
    /// half spin about a revolution's axis, quarter turns about the frame's axes for a sphere.
    std::vector<Eigen::Isometry3d> representatives() const;
    /// "it spins freely about (0, 0, 1)", "it maps onto itself turned 180 deg about (1, 0, 0)", ...
    std::string sentence() const;
};

/// The self-symmetries of a model surface (its samples with normals, `spacing` apart).
Symmetry find_symmetry(const Surface& model, const SymmetrySettings& settings = {});

/// The fraction of `model`'s samples (up to settings.samples of them) that `X` (model frame) maps onto it.
double fraction_on_itself(const Surface& model, const Eigen::Isometry3d& X,
                          const SymmetrySettings& settings = {});

/// One of the models at its pose (T_frame_model), with its symmetries.
struct PlacedSymmetry {
    const Surface* surface = nullptr;
    const Symmetry* symmetry = nullptr;
    Eigen::Isometry3d T_frame_model = Eigen::Isometry3d::Identity();
};

/// A turn (in the common frame, not the identity) that maps every one of the models onto itself, if any:
/// then they cannot place a scan together. Index of the model whose symmetry it is in `source`; false
/// when they fix all six degrees of freedom together (or none of them has a symmetry).
bool common_symmetry(const std::vector<PlacedSymmetry>& models, Eigen::Isometry3d* turn, std::size_t* source,
                     const SymmetrySettings& settings = {});

}  // namespace partloc
