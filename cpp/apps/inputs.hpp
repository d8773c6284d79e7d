// The two input files of iwr-calibrate, read with the same rules as the Python package:
// a robot TOML (iwr.Robot.to_toml / from_toml) and a measurement CSV (iwr.Measurements.to_csv /
// from_csv). Every problem is an InputError naming the file (and the line, key or column).
#pragma once

#include <string>
#include <vector>

#include "iwr/model.hpp"
#include "toml.hpp"

namespace iwr::app {

struct RobotFile {
    std::string name;
    std::string joint_types;  // "PPRR"
    RowMatrixXd dh;           // n x 4: alpha, a, d, theta
    RowMatrixXd joint_limits; // n x 2
    LegMatrix base, platform;
    LegVector leg_offsets;
    Eigen::Matrix<double, kLegs, 2, Eigen::RowMajor> leg_stroke;
    Eigen::Matrix<double, 6, 1> home_pose, workspace;

    Geometry geometry() const;
    /// 4 n + 42 names in the public order of docs/model.md (as iwr.Robot.parameter_names).
    std::vector<std::string> parameter_names() const;
    /// True where a parameter is an angle (rad), as iwr.Robot.angle_parameters.
    std::vector<bool> angle_parameters() const;
};

/// Reads and validates a robot TOML file (the checks of iwr.Robot.from_dict).
RobotFile read_robot(const std::string& path);
RobotFile robot_from_toml(const TomlValue& root, const std::string& file);

struct MeasurementFile {
    std::string joint_types;  // from the units of the q columns
    RowMatrixXd q, poses, legs;
    RowMatrixXd weights;      // empty when the file has no w columns
    std::vector<int> lines;   // the line of each row in the file
    int n_poses() const { return static_cast<int>(poses.rows()); }
};

/// Reads a measurement CSV with the rules of iwr.Measurements.from_csv, and the same messages:
/// UTF-8 text, Python's line breaks, whitespace and float(); the header; every bad row (all of
/// them named, none dropped); then the checks that need no robot: repeated poses, angles in
/// degrees, lengths in metres. A negative weight is a bad row here, named by its line.
MeasurementFile read_measurements(const std::string& path);
MeasurementFile parse_measurements(const std::string& text, const std::string& file);

/// The checks of iwr.Measurements.check against the robot (as `iwr calibrate` makes them): joint
/// types, lengths in metres for the robot's size, unreachable poses (joint readings outside the
/// limits, leg readings outside the stroke, by more than 1 % of the range).
void check_measurements(const MeasurementFile& m, const RobotFile& robot, const std::string& file);

/// Search bounds as iwr.Robot.default_bounds: "default" (+-0.5 mm, +-0.5 degree) or "paper"
/// (Table 2: +-0.5 for every parameter).
void default_bounds(const RobotFile& robot, const std::string& kind, VectorXd& lower,
                    VectorXd& upper);

}  // namespace iwr::app
