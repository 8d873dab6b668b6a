#include "icars/sim/svg_plot.h"

#include <fmt/format.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <fstream>
#include <iterator>
#include <limits>
#include <map>
#include <optional>
#include <stdexcept>
#include <string_view>

#include "icars/sim/planner.h"

namespace icars::sim {

namespace {

// Layout in SVG pixels.
constexpr double kMargin = 40;       // left, and right of the plan (labels may run into it)
constexpr double kRightMargin = 90;  // labels of things near the right wall
constexpr double kTitleBand = 64;    // title and subtitle above the plan
constexpr double kLegendGap = 36;    // between the plan and the legend
constexpr double kLegendRow = 20;
constexpr double kMinWidth = 520;

constexpr std::string_view kRobotColours[] = {"#d62728", "#1f77b4", "#2ca02c",
                                              "#17becf", "#bcbd22", "#8c564b"};
constexpr std::string_view kUserColours[] = {"#ff7f0e", "#e377c2", "#7f7f7f", "#b15928"};
constexpr std::string_view kWaypointColour = "#ffffff";
constexpr std::string_view kPatrolColour = "#6a3d9a";
constexpr std::string_view kDeviceColour = "#444444";
constexpr std::string_view kDoorColour = "#a0522d";
constexpr std::string_view kFurnitureColour = "#c8c8c8";
constexpr std::string_view kMarkColour = "#ffd700";

template <typename... Args>
void put(std::string& out, fmt::format_string<Args...> format, Args&&... args) {
  fmt::format_to(std::back_inserter(out), format, std::forward<Args>(args)...);
}

// Text for XML content and attribute values: the five special characters as entities, and
// control characters XML 1.0 cannot hold as '?'.
std::string escape(std::string_view text) {
  std::string out;
  out.reserve(text.size());
  for (const char c : text) {
    switch (c) {
      case '&':
        out.append("&amp;");
        break;
      case '<':
        out.append("&lt;");
        break;
      case '>':
        out.append("&gt;");
        break;
      case '"':
        out.append("&quot;");
        break;
      case '\'':
        out.append("&apos;");
        break;
      default: {
        const auto u = static_cast<unsigned char>(c);
        out.push_back(u < 0x20 && c != '\t' && c != '\n' && c != '\r' ? '?' : c);
      }
    }
  }
  return out;
}

// Rough width of a label in pixels, for fitting and wrapping (no font metrics here).
double text_width(std::string_view text, double font_size) {
  return 0.6 * font_size * static_cast<double>(text.size());
}

// A label's box in SVG pixels, halo included: from a font size above its baseline to 0.3 of one
// below (descenders), as wide as text_width() estimates.
struct Box {
  double left, top, right, bottom;
  bool overlaps(const Box& o) const {
    return left < o.right && o.left < right && top < o.bottom && o.top < bottom;
  }
};

Box label_box(double x, double baseline, double size, std::string_view label) {
  constexpr double halo = 1.25;  // half the halo's stroke width
  return {x - halo, baseline - size - halo, x + text_width(label, size) + halo,
          baseline + 0.3 * size + halo};
}

// The labels placed so far, so that a later one keeps clear of them.
class LabelLayout {
 public:
  // The baseline for a label at x preferred on `baseline`: that one when the label's box
  // covers no placed label, else the nearest clear row stepping `direction` (-1 up, +1 down;
  // rows above the document's top are skipped), then the other way; `baseline` itself when no
  // row within kMaxRows is clear (an overprint rather than a label far from its point). The
  // label is then placed there.
  double place(double x, double baseline, double size, std::string_view label, int direction) {
    constexpr int kMaxRows = 40;
    const Box at = label_box(x, baseline, size, label);
    const double step = at.bottom - at.top;
    const auto clear = [&](const Box& box) {
      return box.top >= 0 && std::none_of(placed_.begin(), placed_.end(),
                                           [&](const Box& b) { return b.overlaps(box); });
    };
    double chosen = baseline;
    bool found = false;
    for (const int sign : {direction, -direction}) {
      for (int row = sign == direction ? 0 : 1; row <= kMaxRows && !found; ++row) {
        const double candidate = baseline + sign * row * step;
        if (clear(label_box(x, candidate, size, label))) {
          chosen = candidate;
          found = true;
        }
      }
    }
    placed_.push_back(label_box(x, chosen, size, label));
    return chosen;
  }

 private:
  std::vector<Box> placed_;
};

// Joins a track's positions the way its body moves between them: straight where a body of its
// radius fits, else along the path plan_path() finds, so that the line never cuts through a
// wall between positions that are far apart (a user is reported only when their room, posture
// or furniture changes). One grid per radius, made when first needed.
class TrackRouter {
 public:
  explicit TrackRouter(const House& house) : house_(house) {}

  std::vector<Point> route(const PlotTrack& track, double radius) {
    std::vector<Point> line;
    for (const auto& [time, p] : track.points) {
      if (!line.empty() && distance(line.back(), p) > kSame) {
        const OccupancyGrid& g = grid(radius);
        if (!g.segment_free(line.back(), p)) {
          for (const Point q : detour(g, line.back(), p)) line.push_back(q);
        }
      }
      line.push_back(p);
    }
    return line;
  }

 private:
  static constexpr double kSame = 1e-9;  // m: one point
  // How far a position may lie inside an obstacle (a user sitting on a bed) and still be
  // joined to the free space around it.
  static constexpr double kSnapDistance = 2.0;

  const OccupancyGrid& grid(double radius) {
    return grids_.try_emplace(radius, house_, radius).first->second;
  }

  // The points strictly between a and b of the planned way from a to b; none (a straight
  // line) when there is no way, as in a house that does not fit the track.
  static std::vector<Point> detour(const OccupancyGrid& g, Point a, Point b) {
    const auto from = g.nearest_free(a, kSnapDistance);
    if (!from) return {};
    const auto to = g.nearest_free(b, kSnapDistance, *from);
    if (!to) return {};
    auto path = plan_path(g, *from, *to);
    if (!path) return {};
    std::vector<Point> via;
    for (const Point q : *path) {
      const Point last = via.empty() ? a : via.back();
      if (distance(q, last) > kSame && distance(q, b) > kSame) via.push_back(q);
    }
    return via;
  }

  const House& house_;
  std::map<double, OccupancyGrid> grids_;
};

// House metres to SVG pixels: x to the right, y flipped so that up in the house is up.
struct Frame {
  Point min, max;  // the plotted extent in metres
  double x(double metres) const { return kMargin + (metres - min.x) * kSvgPixelsPerMetre; }
  double y(double metres) const { return kTitleBand + (max.y - metres) * kSvgPixelsPerMetre; }
  double plan_width() const { return (max.x - min.x) * kSvgPixelsPerMetre; }
  double plan_height() const { return (max.y - min.y) * kSvgPixelsPerMetre; }
};

// The rooms' bounding box, grown to hold every point drawn (a hand-built house or run may
// stray outside it), at least a metre each way.
Frame frame_for(const House& house, const PlotData& data) {
  constexpr double inf = std::numeric_limits<double>::infinity();
  Point lo{inf, inf};
  Point hi{-inf, -inf};
  const auto grow = [&](Point p) {
    lo = {std::min(lo.x, p.x), std::min(lo.y, p.y)};
    hi = {std::max(hi.x, p.x), std::max(hi.y, p.y)};
  };
  for (const auto& r : house.rooms) {
    grow(r.area.min);
    grow(r.area.max);
  }
  for (const auto& w : house.waypoints) grow(w.at);
  for (const auto& d : house.devices) {
    if (d.carrier.empty()) grow(d.pose.position());
  }
  for (const auto* tracks : {&data.robots, &data.users}) {
    for (const auto& t : *tracks) {
      for (const auto& [time, p] : t.points) grow(p);
    }
  }
  for (const auto& m : data.marks) grow(m.at);
  if (lo.x > hi.x) lo = hi = Point{0, 0};  // nothing at all
  if (hi.x - lo.x < 1) hi.x = lo.x + 1;
  if (hi.y - lo.y < 1) hi.y = lo.y + 1;
  return Frame{lo, hi};
}

// A label with a light halo, so that it stays legible over lines and other labels.
void text(std::string& out, double x, double y, double size, std::string_view fill,
          std::string_view label, std::string_view extra = {}) {
  put(out,
      "<text x=\"{:.1f}\" y=\"{:.1f}\" font-size=\"{}\" fill=\"{}\" stroke=\"#ffffff\" "
      "stroke-width=\"2.5\" stroke-opacity=\"0.8\" stroke-linejoin=\"round\" "
      "paint-order=\"stroke\"{}>{}</text>\n",
      x, y, size, fill, extra, escape(label));
}

void draw_house(std::string& out, const House& house, const Frame& f) {
  out.append("<g class=\"rooms\">\n");
  for (const auto& r : house.rooms) {
    put(out,
        "<rect class=\"room\" data-name=\"{}\" x=\"{:.1f}\" y=\"{:.1f}\" width=\"{:.1f}\" "
        "height=\"{:.1f}\" fill=\"#fbfbf8\" stroke=\"#bbbbbb\" stroke-width=\"1\"/>\n",
        escape(r.name), f.x(r.area.min.x), f.y(r.area.max.y),
        r.area.width() * kSvgPixelsPerMetre, r.area.height() * kSvgPixelsPerMetre);
  }
  out.append("</g>\n<g class=\"furniture\">\n");
  for (const auto& fu : house.furniture) {
    const double w = fu.area.width() * kSvgPixelsPerMetre;
    const double h = fu.area.height() * kSvgPixelsPerMetre;
    put(out,
        "<rect class=\"furniture\" data-name=\"{}\" x=\"{:.1f}\" y=\"{:.1f}\" width=\"{:.1f}\" "
        "height=\"{:.1f}\" fill=\"{}\" stroke=\"#999999\" stroke-width=\"1\"{}><title>{} "
        "({})</title></rect>\n",
        escape(fu.name), f.x(fu.area.min.x), f.y(fu.area.max.y), w, h,
        fu.blocks ? kFurnitureColour : "#ebebeb", fu.blocks ? "" : " stroke-dasharray=\"3 2\"",
        escape(fu.name), escape(fu.kind));
    // In the bottom-left corner: clear of a device standing in the middle (the TV on its
    // stand) and of the room's name when the piece stands in the room's top-left corner.
    constexpr double size = 9;
    if (text_width(fu.name, size) <= w - 6 && h >= size + 4) {
      text(out, f.x(fu.area.min.x) + 3, f.y(fu.area.min.y) - 3, size, "#333333", fu.name);
    }
  }
  out.append("</g>\n<g class=\"walls\" stroke=\"#333333\" stroke-width=\"3\" "
             "stroke-linecap=\"square\">\n");
  for (const auto& w : house.walls) {
    put(out, "<line x1=\"{:.1f}\" y1=\"{:.1f}\" x2=\"{:.1f}\" y2=\"{:.1f}\"/>\n", f.x(w.a.x),
        f.y(w.a.y), f.x(w.b.x), f.y(w.b.y));
  }
  out.append("</g>\n<g class=\"doors\">\n");
  for (const auto& d : house.doors) {
    put(out,
        "<line class=\"door\" data-name=\"{}\" x1=\"{:.1f}\" y1=\"{:.1f}\" x2=\"{:.1f}\" "
        "y2=\"{:.1f}\" stroke=\"{}\" stroke-width=\"3\" stroke-dasharray=\"4 3\"><title>{}</title>"
        "</line>\n",
        escape(d.name), f.x(d.a.x), f.y(d.a.y), f.x(d.b.x), f.y(d.b.y), kDoorColour,
        escape(d.name));
  }
  out.append("</g>\n<g class=\"room-names\">\n");
  for (const auto& r : house.rooms) {
    text(out, f.x(r.area.min.x) + 6, f.y(r.area.max.y) + 16, 13, "#555555", r.name,
         " font-weight=\"bold\"");
  }
  out.append("</g>\n<g class=\"waypoints\">\n");
  for (const auto& w : house.waypoints) {
    const bool patrol = std::find(w.tags.begin(), w.tags.end(), "patrol") != w.tags.end();
    const double x = f.x(w.at.x);
    const double y = f.y(w.at.y);
    put(out,
        "<polygon class=\"waypoint{}\" data-name=\"{}\" points=\"{:.1f},{:.1f} {:.1f},{:.1f} "
        "{:.1f},{:.1f} {:.1f},{:.1f}\" fill=\"{}\" stroke=\"{}\" stroke-width=\"1.2\"/>\n",
        patrol ? " patrol" : "", escape(w.name), x, y - 5, x + 5, y, x, y + 5, x - 5, y,
        patrol ? kPatrolColour : kWaypointColour, patrol ? kPatrolColour : "#555555");
    text(out, x + 7, y + 10, 9, patrol ? kPatrolColour : "#555555", w.name);
  }
  out.append("</g>\n<g class=\"devices\">\n");
  for (const auto& d : house.devices) {
    if (!d.carrier.empty()) continue;  // carried devices go where their robot goes
    const double x = f.x(d.pose.x);
    const double y = f.y(d.pose.y);
    put(out,
        "<circle class=\"device\" data-name=\"{}\" cx=\"{:.1f}\" cy=\"{:.1f}\" r=\"3.5\" "
        "fill=\"{}\" stroke=\"#ffffff\" stroke-width=\"1\"><title>{} ({})</title></circle>\n",
        escape(d.id), x, y, kDeviceColour, escape(d.id), escape(d.type));
    text(out, x + 5, y - 5, 9, kDeviceColour, d.id);
  }
  out.append("</g>\n");
}

// A robot's track is a solid line; a user's a dashed line with a dot at every position. `line`
// is the track's positions joined as TrackRouter joins them.
void draw_track(std::string& out, const PlotTrack& track, const std::vector<Point>& line,
                std::string_view colour, bool robot, const Frame& f, LabelLayout& labels) {
  if (track.points.empty()) return;
  const std::string_view kind = robot ? "robot-track" : "user-track";
  put(out, "<g class=\"{}-group\" data-name=\"{}\">\n", kind, escape(track.name));
  std::string points;
  for (const Point p : line) {
    if (!points.empty()) points.push_back(' ');
    put(points, "{:.1f},{:.1f}", f.x(p.x), f.y(p.y));
  }
  put(out,
      "<polyline class=\"{}\" data-name=\"{}\" points=\"{}\" fill=\"none\" stroke=\"{}\" "
      "stroke-width=\"{}\" stroke-linejoin=\"round\"{}/>\n",
      kind, escape(track.name), points, colour, robot ? 2 : 1.2,
      robot ? "" : " stroke-dasharray=\"4 3\"");
  if (!robot) {
    for (const auto& [time, p] : track.points) {
      put(out, "<circle cx=\"{:.1f}\" cy=\"{:.1f}\" r=\"2\" fill=\"{}\"/>\n", f.x(p.x), f.y(p.y),
          colour);
    }
  }
  const auto& [t0, p0] = track.points.front();
  const auto& [t1, p1] = track.points.back();
  const double x0 = f.x(p0.x);
  const double y0 = f.y(p0.y);
  const double x1 = f.x(p1.x);
  const double y1 = f.y(p1.y);
  put(out,
      "<circle class=\"start\" cx=\"{:.1f}\" cy=\"{:.1f}\" r=\"5\" fill=\"#ffffff\" "
      "stroke=\"{}\" stroke-width=\"2\"/>\n",
      x0, y0, colour);
  constexpr double size = 10;
  const std::string start_label = fmt::format("{} {}", track.name, format_time(t0));
  text(out, x0 + 7, labels.place(x0 + 7, y0 - 7, size, start_label, -1), size, colour,
       start_label, " class=\"time\"");
  if (track.points.size() > 1) {
    put(out,
        "<rect class=\"end\" x=\"{:.1f}\" y=\"{:.1f}\" width=\"8\" height=\"8\" fill=\"{}\"/>\n",
        x1 - 4, y1 - 4, colour);
    const std::string end_label = format_time(t1);
    text(out, x1 + 7, labels.place(x1 + 7, y1 + 14, size, end_label, +1), size, colour, end_label,
         " class=\"time\"");
  }
  out.append("</g>\n");
}

void draw_mark(std::string& out, const PlotMark& m, const Frame& f, LabelLayout& labels) {
  constexpr double size = 11;
  const double x = f.x(m.at.x);
  const double y = f.y(m.at.y);
  const double preferred = y - 14;
  const double baseline = labels.place(x + 6, preferred, size, m.label, -1);
  put(out,
      "<g class=\"mark\"><title>{} at {}</title>\n"
      "<line x1=\"{:.1f}\" y1=\"{:.1f}\" x2=\"{:.1f}\" y2=\"{:.1f}\" stroke=\"#000000\" "
      "stroke-width=\"1.2\"/>\n"
      "<circle cx=\"{:.1f}\" cy=\"{:.1f}\" r=\"4\" fill=\"{}\" stroke=\"#000000\"/>\n",
      escape(m.label), format_time(m.time), x, y, x, y - 16, x, y - 16, kMarkColour);
  if (baseline != preferred) {  // moved clear of another label: a leader from the pin
    put(out,
        "<line class=\"leader\" x1=\"{:.1f}\" y1=\"{:.1f}\" x2=\"{:.1f}\" y2=\"{:.1f}\" "
        "stroke=\"#000000\" stroke-width=\"0.6\"/>\n",
        x, y - 16, x + 5, baseline - size / 3);
  }
  text(out, x + 6, baseline, size, "#000000", m.label, " font-weight=\"bold\"");
  out.append("</g>\n");
}

// One legend entry: a symbol and what it stands for.
struct LegendEntry {
  enum class Symbol { line, dashed, diamond, dot, rect, door, pin, start, end } symbol;
  std::string colour;
  std::string label;
};

void draw_symbol(std::string& out, const LegendEntry& e, double x, double y) {
  using S = LegendEntry::Symbol;
  switch (e.symbol) {
    case S::line:
      put(out,
          "<line x1=\"{:.1f}\" y1=\"{:.1f}\" x2=\"{:.1f}\" y2=\"{:.1f}\" stroke=\"{}\" "
          "stroke-width=\"2\"/>\n",
          x, y, x + 20, y, e.colour);
      break;
    case S::dashed:
      put(out,
          "<line x1=\"{:.1f}\" y1=\"{:.1f}\" x2=\"{:.1f}\" y2=\"{:.1f}\" stroke=\"{}\" "
          "stroke-width=\"1.2\" stroke-dasharray=\"4 3\"/>\n<circle cx=\"{:.1f}\" cy=\"{:.1f}\" "
          "r=\"2\" fill=\"{}\"/>\n",
          x, y, x + 20, y, e.colour, x + 10, y, e.colour);
      break;
    case S::diamond:
      put(out,
          "<polygon points=\"{:.1f},{:.1f} {:.1f},{:.1f} {:.1f},{:.1f} {:.1f},{:.1f}\" "
          "fill=\"{}\" stroke=\"{}\" stroke-width=\"1.2\"/>\n",
          x + 10, y - 5, x + 15, y, x + 10, y + 5, x + 5, y, e.colour,
          e.colour == kWaypointColour ? "#555555" : e.colour);
      break;
    case S::dot:
      put(out, "<circle cx=\"{:.1f}\" cy=\"{:.1f}\" r=\"3.5\" fill=\"{}\"/>\n", x + 10, y,
          e.colour);
      break;
    case S::rect:
      put(out,
          "<rect x=\"{:.1f}\" y=\"{:.1f}\" width=\"20\" height=\"10\" fill=\"{}\" "
          "stroke=\"#999999\"/>\n",
          x, y - 5, e.colour);
      break;
    case S::door:
      put(out,
          "<line x1=\"{:.1f}\" y1=\"{:.1f}\" x2=\"{:.1f}\" y2=\"{:.1f}\" stroke=\"{}\" "
          "stroke-width=\"3\" stroke-dasharray=\"4 3\"/>\n",
          x, y, x + 20, y, e.colour);
      break;
    case S::pin:
      put(out,
          "<line x1=\"{:.1f}\" y1=\"{:.1f}\" x2=\"{:.1f}\" y2=\"{:.1f}\" stroke=\"#000000\"/>\n"
          "<circle cx=\"{:.1f}\" cy=\"{:.1f}\" r=\"4\" fill=\"{}\" stroke=\"#000000\"/>\n",
          x + 10, y + 6, x + 10, y - 2, x + 10, y - 3, e.colour);
      break;
    case S::start:
      put(out,
          "<circle cx=\"{:.1f}\" cy=\"{:.1f}\" r=\"5\" fill=\"#ffffff\" stroke=\"{}\" "
          "stroke-width=\"2\"/>\n",
          x + 10, y, e.colour);
      break;
    case S::end:
      put(out, "<rect x=\"{:.1f}\" y=\"{:.1f}\" width=\"8\" height=\"8\" fill=\"{}\"/>\n", x + 6,
          y - 4, e.colour);
      break;
  }
}

std::vector<LegendEntry> legend_entries(const PlotData& data) {
  using S = LegendEntry::Symbol;
  std::vector<LegendEntry> entries;
  for (std::size_t i = 0; i < data.robots.size(); ++i) {
    entries.push_back({S::line, std::string(kRobotColours[i % std::size(kRobotColours)]),
                       data.robots[i].name});
  }
  for (std::size_t i = 0; i < data.users.size(); ++i) {
    entries.push_back({S::dashed, std::string(kUserColours[i % std::size(kUserColours)]),
                       data.users[i].name});
  }
  entries.push_back({S::start, "#555555", "start"});
  entries.push_back({S::end, "#555555", "end"});
  entries.push_back({S::diamond, std::string(kWaypointColour), "waypoint"});
  entries.push_back({S::diamond, std::string(kPatrolColour), "patrol waypoint"});
  entries.push_back({S::dot, std::string(kDeviceColour), "device"});
  entries.push_back({S::rect, std::string(kFurnitureColour), "furniture"});
  entries.push_back({S::door, std::string(kDoorColour), "door"});
  if (!data.marks.empty()) entries.push_back({S::pin, std::string(kMarkColour), "mark"});
  return entries;
}

}  // namespace

std::string render_svg(const House& house, const PlotData& data) {
  const Frame f = frame_for(house, data);
  const double width = std::max(kMinWidth, kMargin + f.plan_width() + kRightMargin);
  constexpr double font = 11;

  // The legend's entries flow left to right and wrap; lay them out first to know the height.
  const auto entries = legend_entries(data);
  std::vector<std::pair<double, double>> at;  // each entry's position
  const double legend_top = kTitleBand + f.plan_height() + kLegendGap;
  double x = kMargin;
  double y = legend_top;
  for (const auto& e : entries) {
    const double w = 26 + text_width(e.label, font) + 18;
    if (x > kMargin && x + w > width - kMargin) {
      x = kMargin;
      y += kLegendRow;
    }
    at.emplace_back(x, y);
    x += w;
  }
  const double height = y + kLegendRow;

  std::string out;
  out.reserve(16384);
  put(out,
      "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n"
      "<svg xmlns=\"http://www.w3.org/2000/svg\" version=\"1.1\" width=\"{0:.0f}\" "
      "height=\"{1:.0f}\" viewBox=\"0 0 {0:.0f} {1:.0f}\" font-family=\"sans-serif\">\n",
      width, height);
  const std::string& title = data.title.empty() ? house.name : data.title;
  put(out, "<title>{}</title>\n", escape(title));
  put(out, "<rect width=\"{:.0f}\" height=\"{:.0f}\" fill=\"#ffffff\"/>\n", width, height);
  text(out, kMargin, 28, 18, "#000000", title, " class=\"title\" font-weight=\"bold\"");

  // The subtitle: the house and the run's span, or the time the data spans.
  std::optional<std::pair<Time, Time>> span;
  const auto extend = [&](Time t) {
    span = span ? std::pair{std::min(span->first, t), std::max(span->second, t)} : std::pair{t, t};
  };
  for (const auto* tracks : {&data.robots, &data.users}) {
    for (const auto& t : *tracks) {
      for (const auto& [time, p] : t.points) extend(time);
    }
  }
  for (const auto& m : data.marks) extend(m.time);
  if (data.run_start || data.run_end) {
    const Time start = data.run_start.value_or(span ? span->first : *data.run_end);
    const Time end = data.run_end.value_or(span ? span->second : *data.run_start);
    span = std::pair{start, end};
  }
  std::string subtitle = fmt::format("house {}", house.name);
  if (span) {
    subtitle = fmt::format("{}, {} to {}", subtitle, format_time(span->first),
                           format_time(span->second));
  }
  text(out, kMargin, 48, 11, "#555555", subtitle, " class=\"subtitle\"");

  draw_house(out, house, f);
  TrackRouter router(house);
  LabelLayout labels;
  out.append("<g class=\"users\">\n");
  for (std::size_t i = 0; i < data.users.size(); ++i) {
    const auto& track = data.users[i];
    const auto* spec = house.user(track.name);
    const auto line = router.route(track, spec ? spec->radius : UserSpec{}.radius);
    draw_track(out, track, line, kUserColours[i % std::size(kUserColours)], false, f, labels);
  }
  out.append("</g>\n<g class=\"robots\">\n");
  for (std::size_t i = 0; i < data.robots.size(); ++i) {
    const auto& track = data.robots[i];
    const auto* spec = house.robot(track.name);
    const auto line = router.route(track, spec ? spec->radius : RobotSpec{}.radius);
    draw_track(out, track, line, kRobotColours[i % std::size(kRobotColours)], true, f, labels);
  }
  out.append("</g>\n<g class=\"marks\">\n");
  for (const auto& m : data.marks) draw_mark(out, m, f, labels);
  out.append("</g>\n<g class=\"legend\">\n");
  for (std::size_t i = 0; i < entries.size(); ++i) {
    const auto [ex, ey] = at[i];
    draw_symbol(out, entries[i], ex, ey);
    text(out, ex + 26, ey + font / 3, font, "#333333", entries[i].label);
  }
  out.append("</g>\n</svg>\n");
  return out;
}

void write_svg(const std::string& path, const House& house, const PlotData& data) {
  const std::string svg = render_svg(house, data);
  errno = 0;
  std::ofstream file(path, std::ios::binary | std::ios::trunc);
  if (file) file.write(svg.data(), static_cast<std::streamsize>(svg.size()));
  if (file) file.close();
  if (!file) {
    const int error = errno;
    throw std::runtime_error(fmt::format("cannot write the SVG plot to \"{}\": {}", path,
                                         error != 0 ? std::strerror(error) : "write failed"));
  }
}

}  // namespace icars::sim
