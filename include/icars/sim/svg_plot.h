// A picture of a house and of what happened in it: an SVG plan view with the rooms, walls and
// doors, furniture, waypoints and static devices, the robots' and users' tracks over a run,
// and marks for moments worth pointing at ("RestMode", "found user1"). For reading a run by
// eye, in a browser or a report; nothing reads it back.
//
// The plan is drawn at a fixed scale (kSvgPixelsPerMetre) with y up as in the house frame, so
// plots of the same house line up. Every label is escaped, so any name or text may be shown.
#pragma once

#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "icars/clock/time.h"
#include "icars/sim/house.h"

namespace icars::sim {

inline constexpr double kSvgPixelsPerMetre = 80.0;

struct PlotTrack {  // a moving thing's positions over the run, in time order
  std::string name;  // "robot1", "user1"
  std::vector<std::pair<Time, Point>> points;
};

struct PlotMark {  // something worth pointing at: "RestMode", "found user1"
  Time time{0};
  Point at;
  std::string label;
};

struct PlotData {
  std::string title;  // "" shows the house's name
  // The run's start and end, shown in the subtitle; unset, the subtitle shows the time the
  // tracks and marks span instead.
  std::optional<Time> run_start, run_end;
  std::vector<PlotTrack> robots;
  std::vector<PlotTrack> users;
  std::vector<PlotMark> marks;
};

// A complete, well-formed SVG document (UTF-8). Each track is a polyline of class
// "robot-track" or "user-track" with attribute data-name, its points in SVG pixels; empty
// tracks draw nothing but keep their legend entry. Between two positions a track goes straight
// where a body of the robot's or user's radius (RobotSpec, UserSpec; the defaults for names
// the house does not know) fits, and along the path plan_path() finds for it elsewhere, so a
// track never cuts through a wall between sparse positions; a user's dots mark the positions
// themselves. The time labels of the tracks and the marks' labels never overlap one another:
// a label that would cover an earlier one is moved up (a start's label, a mark's) or down (an
// end's), with a thin line from a moved mark's pin to its label.
std::string render_svg(const House& house, const PlotData& data);

// Writes render_svg() to `path`; throws std::runtime_error naming the path when it cannot.
void write_svg(const std::string& path, const House& house, const PlotData& data);

}  // namespace icars::sim
