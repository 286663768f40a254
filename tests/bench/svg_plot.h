// Small SVG line/scatter charts for the benchmark programs (run time against error and the like).
// Standard library only: build a Chart, then renderSvg() for the text or writeSvg() for a file.
//
// Layout: title on top, plot area with light grid, ticks and labels on a frame, axis labels, and
// the legend in a column to the right of the plot area (the canvas is widened for it, so it never
// covers data). Linear axes use 1/2/5 x 10^n tick steps; log10 axes use decade ticks (labels 0.01
// ... 1000, then 10 with a superscript exponent) with minor ticks at 2..9. Points with non-finite
// coordinates, or non-positive ones on a log axis, are skipped (and break the polyline).
#pragma once

#include <algorithm>
#include <array>
#include <charconv>
#include <cmath>
#include <cstddef>
#include <filesystem>
#include <fstream>
#include <ios>
#include <limits>
#include <optional>
#include <string>
#include <string_view>
#include <system_error>
#include <utility>
#include <vector>

namespace compose::bench {

struct Series {
  std::string label;         // legend text; empty = not listed in the legend
  std::vector<double> x, y;  // same length (extra values of the longer one are ignored)
  bool lines = true;         // connect points in the given order (else markers only)
  std::string color;         // any SVG colour; empty = next colour of the Okabe-Ito palette
  std::string dash;          // SVG stroke-dasharray, e.g. "6 3"; empty = solid
};

struct Chart {
  std::string title, xLabel, yLabel;
  bool logX = false, logY = false;  // log10 axes with decade ticks
  std::vector<Series> series;
  int width = 900, height = 560;                 // pixels; the legend column is added to the width
  std::optional<double> yMin, yMax, xMin, xMax;  // override autoscale
  std::vector<std::pair<double, std::string>> hLines;  // horizontal reference lines (y, label)
};

namespace svg_detail {

// Okabe-Ito, reordered so the strongest colours come first and yellow (weak on white) last.
inline constexpr std::array<const char*, 8> kPalette = {"#0072B2", "#D55E00", "#009E73", "#CC79A7",
                                                        "#E69F00", "#56B4E9", "#000000", "#F0E442"};

inline constexpr double kTickFont = 12, kLabelFont = 14, kTitleFont = 17, kLegendFont = 13;
inline constexpr const char* kMinus = "\xE2\x88\x92";  // U+2212 MINUS SIGN

inline std::string escapeXml(std::string_view s) {
  std::string out;
  out.reserve(s.size());
  for (const char c : s) {
    switch (c) {
      case '&':
        out += "&amp;";
        break;
      case '<':
        out += "&lt;";
        break;
      case '>':
        out += "&gt;";
        break;
      case '"':
        out += "&quot;";
        break;
      case '\'':
        out += "&apos;";
        break;
      default:
        out += c;
    }
  }
  return out;
}

// Locale-independent fixed-point formatting; never prints "-0".
inline std::string fixed(double v, int decimals) {
  char buf[400];
  const auto r = std::to_chars(buf, buf + sizeof buf, v, std::chars_format::fixed, decimals);
  if (r.ec != std::errc()) return "0";
  std::string s(buf, r.ptr);
  if (!s.empty() && s[0] == '-' && s.find_first_not_of("0.", 1) == std::string::npos) s.erase(0, 1);
  return s;
}

// Pixel coordinate: two decimals, trailing zeros dropped.
inline std::string px(double v) {
  if (!std::isfinite(v)) v = 0;
  std::string s = fixed(std::clamp(v, -1e6, 1e6), 2);
  while (s.back() == '0') s.pop_back();
  if (s.back() == '.') s.pop_back();
  return s == "-0" ? "0" : s;
}

// "2.5e+06" -> "2.5e6", "1e-05" -> "1e-5".
inline std::string scientific(double v, int decimals) {
  char buf[64];
  const auto r = std::to_chars(buf, buf + sizeof buf, v, std::chars_format::scientific, decimals);
  if (r.ec != std::errc()) return "0";
  const std::string s(buf, r.ptr);
  const std::size_t e = s.find('e');
  if (e == std::string::npos) return s;
  std::string exp = s.substr(e + 1);
  const bool neg = !exp.empty() && exp[0] == '-';
  std::size_t i = (!exp.empty() && (exp[0] == '+' || exp[0] == '-')) ? 1 : 0;
  while (i + 1 < exp.size() && exp[i] == '0') ++i;
  return s.substr(0, e) + "e" + (neg ? "-" : "") + exp.substr(i);
}

// Rough rendered width of text in a common sans-serif font (slightly generous).
inline double textWidth(std::string_view s, double fontSize) {
  double em = 0;
  for (const char c : s) {
    if ((static_cast<unsigned char>(c) & 0xC0U) == 0x80U) continue;  // UTF-8 continuation
    if (c >= '0' && c <= '9') {
      em += 0.64;
    } else if (c >= 'A' && c <= 'Z') {
      em += 0.70;
    } else if (c == ' ' || c == '.' || c == ',' || c == ':' || c == ';' || c == 'i' || c == 'l' ||
               c == 'j' || c == '(' || c == ')' || c == '[' || c == ']' || c == '|' || c == '\'') {
      em += 0.34;
    } else if (c == 'm' || c == 'w' || c == 'M' || c == 'W' || c == '@') {
      em += 0.90;
    } else {
      em += 0.58;
    }
  }
  return em * fontSize;
}

struct Tick {
  double value = 0;
  std::string text, sup;  // label, with an optional superscript (exponent); both empty = minor
  bool major = true;      // major ticks are labelled and get the darker grid line
};

inline double tickLabelWidth(const Tick& t) {
  return textWidth(t.text, kTickFont) + textWidth(t.sup, kTickFont * 0.75);
}

inline double niceStep(double span, int maxTicks) {
  const double raw = span / std::max(1, maxTicks);
  const double mag = std::pow(10.0, std::floor(std::log10(raw)));
  for (const double m : {1.0, 2.0, 5.0}) {
    if (m * mag >= raw * (1 - 1e-9)) return m * mag;
  }
  return 10 * mag;
}

inline std::vector<Tick> linearTicks(double lo, double hi, int maxTicks) {
  std::vector<Tick> ticks;
  const double step = niceStep(hi - lo, maxTicks);
  if (!(step > 0) || !std::isfinite(step)) return ticks;
  const double stepExp = std::floor(std::log10(step) + 1e-9);
  const bool sci = std::max(std::abs(lo), std::abs(hi)) >= 1e6 || step < 1e-4;
  const int decimals = std::max(0, static_cast<int>(-stepExp));
  const double first = std::ceil(lo / step - 1e-9), last = std::floor(hi / step + 1e-9);
  for (double k = first; k <= last && ticks.size() < 200; k += 1) {
    double v = k * step;
    if (std::abs(v) < step * 1e-9) v = 0;
    Tick t;
    t.value = v;
    if (!sci) {
      t.text = fixed(v, decimals);
    } else if (v == 0) {
      t.text = "0";
    } else {
      const double digits = std::floor(std::log10(std::abs(v)) + 1e-9) - stepExp;
      t.text = scientific(v, std::max(0, static_cast<int>(digits)));
    }
    if (t.text[0] == '-') t.text = kMinus + t.text.substr(1);
    ticks.push_back(std::move(t));
  }
  return ticks;
}

inline Tick logTick(int mant, int e, bool labelled) {
  Tick t;
  t.value = mant * std::pow(10.0, e);
  t.major = labelled;
  if (!labelled) return t;
  if (e >= -2 && e <= 3) {
    t.text = fixed(t.value, std::max(0, -e));
  } else {
    t.text = mant == 1 ? "10"
                       : std::to_string(mant) +
                             "\xC3\x97"
                             "10";  // U+00D7 times
    t.sup = (e < 0 ? std::string(kMinus) : std::string()) + std::to_string(std::abs(e));
  }
  return t;
}

inline std::vector<Tick> logTicks(double lo, double hi, int maxLabels) {
  std::vector<Tick> ticks;
  const double l0 = std::log10(lo), l1 = std::log10(hi);
  const int e0 = static_cast<int>(std::ceil(l0 - 1e-9)),
            e1 = static_cast<int>(std::floor(l1 + 1e-9));
  const int eLow = static_cast<int>(std::floor(l0 + 1e-9));
  const auto inRange = [&](double v) { return v >= lo * (1 - 1e-9) && v <= hi * (1 + 1e-9); };
  const int decades = e1 - e0 + 1;
  if (decades >= 2) {
    const int stride = std::max(1, (decades + maxLabels - 1) / std::max(1, maxLabels));
    const bool labelTwoFive = decades == 2 && maxLabels >= 6;  // a single decade: 1, 2, 5, 10
    for (int e = eLow; e <= e1; ++e) {
      const double dec = std::pow(10.0, e);
      if (inRange(dec)) ticks.push_back(logTick(1, e, ((e % stride) + stride) % stride == 0));
      if (stride == 1 && decades <= 12) {
        for (int m = 2; m <= 9; ++m) {
          if (inRange(m * dec)) ticks.push_back(logTick(m, e, labelTwoFive && (m == 2 || m == 5)));
        }
      }
    }
    return ticks;
  }
  // Less than a decade visible (only with overridden limits): label all of 1..9 if they fit,
  // else 1-2-5 (else fall back to linear ticks).
  for (const bool all : {true, false}) {
    ticks.clear();
    int labelled = 0;
    for (int e = eLow; e <= e1 + 1; ++e) {
      for (int m = 1; m <= 9; ++m) {
        if (!inRange(m * std::pow(10.0, e))) continue;
        const bool lab = all || m == 1 || m == 2 || m == 5;
        labelled += lab ? 1 : 0;
        ticks.push_back(logTick(m, e, lab));
      }
    }
    if (labelled >= 2 && (!all || labelled <= maxLabels)) return ticks;
  }
  ticks = linearTicks(lo, hi, std::max(2, maxLabels));
  std::erase_if(ticks, [](const Tick& t) { return !(t.value > 0); });
  return ticks;
}

inline bool usable(double v, bool log) {
  return std::isfinite(v) && (!log || v > 0);
}

// Axis limits: data extent with 5% padding (log: out to whole decades), then the overrides.
inline std::pair<double, double> axisRange(const std::vector<double>& values, bool log,
                                           std::optional<double> minOverride,
                                           std::optional<double> maxOverride) {
  double lo = std::numeric_limits<double>::infinity(), hi = -lo;
  for (const double v : values) {
    if (usable(v, log)) lo = std::min(lo, v), hi = std::max(hi, v);
  }
  if (log) {
    if (lo > hi) {
      lo = 1, hi = 10;
    } else {
      const double a = std::clamp(std::floor(std::log10(lo) + 1e-9), -300.0, 300.0);
      const double b = std::clamp(std::ceil(std::log10(hi) - 1e-9), -300.0, 300.0);
      lo = std::pow(10.0, a);
      hi = std::pow(10.0, std::max(b, a + 1));
    }
  } else if (lo > hi) {
    lo = 0, hi = 1;
  } else if (hi - lo <= std::abs(hi) * 1e-12) {
    const double d = lo == 0 ? 1 : std::abs(lo) * 0.1;
    lo -= d, hi += d;
  } else {
    const double pad = 0.05 * (hi - lo);
    lo -= pad, hi += pad;
  }
  const bool setLo = minOverride && usable(*minOverride, log);
  const bool setHi = maxOverride && usable(*maxOverride, log);
  if (setLo) lo = *minOverride;
  if (setHi) hi = *maxOverride;
  if (!(hi > lo)) {
    if (setHi && !setLo) {
      lo = log ? hi / 10 : hi - (hi == 0 ? 1 : std::abs(hi));
    } else {
      hi = log ? lo * 10 : lo + (lo == 0 ? 1 : std::abs(lo));
    }
  }
  return {lo, hi};
}

struct Scale {
  double lo, hi;  // data limits
  bool log;
  double p0, p1;  // pixel positions of lo and hi
  double operator()(double v) const {
    const double a = log ? std::log10(v) : v, b0 = log ? std::log10(lo) : lo;
    const double b1 = log ? std::log10(hi) : hi;
    return p0 + (a - b0) / (b1 - b0) * (p1 - p0);
  }
};

inline std::string tickText(const Tick& t, double x, double y, const char* anchor) {
  std::string s = "<text x=\"" + px(x) + "\" y=\"" + px(y) + "\" text-anchor=\"" + anchor + "\">" +
                  escapeXml(t.text);
  if (!t.sup.empty()) {
    s += "<tspan dy=\"-0.45em\" font-size=\"" + px(kTickFont * 0.75) + "\">" + escapeXml(t.sup) +
         "</tspan>";
  }
  return s + "</text>\n";
}

}  // namespace svg_detail

inline std::string renderSvg(const Chart& chart) {
  using namespace svg_detail;
  const double width = std::max(chart.width, 240), height = std::max(chart.height, 180);

  // Axis limits (reference lines count towards the y extent).
  std::vector<double> xs, ys;
  for (const Series& s : chart.series) {
    const std::size_t n = std::min(s.x.size(), s.y.size());
    for (std::size_t i = 0; i < n; ++i) {
      if (usable(s.x[i], chart.logX) && usable(s.y[i], chart.logY)) {
        xs.push_back(s.x[i]);
        ys.push_back(s.y[i]);
      }
    }
  }
  for (const auto& h : chart.hLines) ys.push_back(h.first);
  const auto [x0, x1] = axisRange(xs, chart.logX, chart.xMin, chart.xMax);
  const auto [y0, y1] = axisRange(ys, chart.logY, chart.yMin, chart.yMax);

  // Vertical layout, then y ticks (their label width sets the left margin), then x ticks.
  const double top = chart.title.empty() ? 20 : 48;
  const double bottom = chart.xLabel.empty() ? 38 : 62;
  const double plotH = std::max(60.0, height - top - bottom);
  const int maxY = std::max(2, static_cast<int>(plotH / (chart.logY ? 36 : 50)));
  const std::vector<Tick> yTicks = chart.logY ? logTicks(y0, y1, maxY) : linearTicks(y0, y1, maxY);
  double yTickW = 0;
  for (const Tick& t : yTicks) yTickW = std::max(yTickW, tickLabelWidth(t));
  const double left = 12 + (chart.yLabel.empty() ? 0 : kLabelFont + 12) + yTickW + 12;
  const double right = 30;
  const double plotW = std::max(80.0, width - left - right);
  std::vector<Tick> xTicks;
  for (int maxX = std::max(2, static_cast<int>(plotW / 60));; --maxX) {
    xTicks = chart.logX ? logTicks(x0, x1, maxX) : linearTicks(x0, x1, maxX);
    double widest = 0;
    int labelled = 0;
    for (const Tick& t : xTicks) {
      if (!t.major) continue;
      widest = std::max(widest, tickLabelWidth(t));
      ++labelled;
    }
    if (maxX <= 2 || labelled * (widest + 16) <= plotW) break;
  }
  const double plotL = left, plotR = left + plotW, plotT = top, plotB = top + plotH;
  const Scale sx{x0, x1, chart.logX, plotL, plotR};
  const Scale sy{y0, y1, chart.logY, plotB, plotT};

  // Colours and the legend column.
  std::vector<std::string> colors;
  std::size_t nextColor = 0;
  double legendTextW = 0;
  int legendRows = 0;
  for (const Series& s : chart.series) {
    colors.push_back(s.color.empty() ? kPalette[nextColor++ % kPalette.size()] : s.color);
    if (!s.label.empty()) {
      legendTextW = std::max(legendTextW, textWidth(s.label, kLegendFont));
      ++legendRows;
    }
  }
  constexpr double kRow = 21, kSample = 30;
  const double legendX = plotR + right, legendW = 12 + kSample + 10 + legendTextW + 12;
  const double legendH = 10 + kRow * legendRows + 4;
  const double totalW = legendRows > 0 ? legendX + legendW + 16 : plotR + right;
  const double totalH = std::max(height, plotT + legendH + 12);

  std::string o;
  o.reserve(16384);
  o += "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n";
  o += "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"" + px(totalW) + "\" height=\"" +
       px(totalH) + "\" viewBox=\"0 0 " + px(totalW) + " " + px(totalH) +
       "\" font-family=\"sans-serif\" font-size=\"" + px(kTickFont) + "\">\n";
  if (!chart.title.empty()) o += "<title>" + escapeXml(chart.title) + "</title>\n";
  o += "<rect width=\"100%\" height=\"100%\" fill=\"white\"/>\n";
  // Lines are clipped to the frame; markers slightly outside it, so those on the limits stay whole.
  o += "<defs><clipPath id=\"plot-lines\"><rect x=\"" + px(plotL) + "\" y=\"" + px(plotT) +
       "\" width=\"" + px(plotW) + "\" height=\"" + px(plotH) +
       "\"/></clipPath><clipPath id=\"plot-markers\"><rect x=\"" + px(plotL - 6) + "\" y=\"" +
       px(plotT - 6) + "\" width=\"" + px(plotW + 12) + "\" height=\"" + px(plotH + 12) +
       "\"/></clipPath></defs>\n";

  // Grid: minor lines first (only where decades are wide enough not to look busy), then major.
  const auto decadePixels = [](const Scale& s) {
    return s.log ? std::abs(s.p1 - s.p0) / std::log10(s.hi / s.lo) : 0.0;
  };
  const bool minorX = decadePixels(sx) >= 110, minorY = decadePixels(sy) >= 70;
  o += "<g stroke-width=\"1\" shape-rendering=\"crispEdges\">\n";
  for (const bool major : {false, true}) {
    const char* stroke = major ? "#dcdcdc" : "#f0f0f0";
    for (const Tick& t : xTicks) {
      if (t.major != major || (!major && !minorX)) continue;
      const std::string x = px(sx(t.value));
      o += "<line x1=\"" + x + "\" x2=\"" + x + "\" y1=\"" + px(plotT) + "\" y2=\"" + px(plotB) +
           "\" stroke=\"" + stroke + "\"/>\n";
    }
    for (const Tick& t : yTicks) {
      if (t.major != major || (!major && !minorY)) continue;
      const std::string y = px(sy(t.value));
      o += "<line x1=\"" + px(plotL) + "\" x2=\"" + px(plotR) + "\" y1=\"" + y + "\" y2=\"" + y +
           "\" stroke=\"" + stroke + "\"/>\n";
    }
  }
  o += "</g>\n";

  // Reference lines (under the data); their labels go on top later.
  std::vector<std::pair<double, std::string>> refLabels;
  for (const auto& [value, label] : chart.hLines) {
    if (!usable(value, chart.logY) || value < y0 || value > y1) continue;
    const double y = sy(value);
    o += "<line x1=\"" + px(plotL) + "\" x2=\"" + px(plotR) + "\" y1=\"" + px(y) + "\" y2=\"" +
         px(y) + "\" stroke=\"#555555\" stroke-width=\"1.3\" stroke-dasharray=\"7 4\"/>\n";
    if (!label.empty()) refLabels.emplace_back(y, label);
  }

  // Data: polylines (broken at skipped points), then markers; all lines go under all markers.
  const auto inside = [&](double x, double y) {
    return x >= plotL - 0.5 && x <= plotR + 0.5 && y >= plotT - 0.5 && y <= plotB + 0.5;
  };
  std::string lineSvg = "<g clip-path=\"url(#plot-lines)\">\n";
  std::string markerSvg = "<g clip-path=\"url(#plot-markers)\">\n";
  for (std::size_t si = 0; si < chart.series.size(); ++si) {
    const Series& s = chart.series[si];
    const std::string color = escapeXml(colors[si]);
    const std::size_t n = std::min(s.x.size(), s.y.size());
    std::vector<std::vector<std::pair<double, double>>> runs(1);
    for (std::size_t i = 0; i < n; ++i) {
      if (usable(s.x[i], chart.logX) && usable(s.y[i], chart.logY)) {
        runs.back().emplace_back(sx(s.x[i]), sy(s.y[i]));
      } else if (!runs.back().empty()) {
        runs.emplace_back();
      }
    }
    if (s.lines) {
      for (const auto& run : runs) {
        if (run.size() < 2) continue;
        lineSvg += "<polyline fill=\"none\" stroke=\"" + color +
                   "\" stroke-width=\"2\" stroke-linejoin=\"round\" stroke-linecap=\"round\"";
        if (!s.dash.empty()) lineSvg += " stroke-dasharray=\"" + escapeXml(s.dash) + "\"";
        lineSvg += " points=\"";
        for (const auto& [x, y] : run) lineSvg += px(x) + "," + px(y) + " ";
        lineSvg.back() = '"';
        lineSvg += "/>\n";
      }
    }
    const std::string r = s.lines ? "3.2" : "4.2";
    markerSvg += "<g fill=\"" + color + "\" stroke=\"white\" stroke-width=\"" +
                 std::string(s.lines ? "1" : "0.8") + "\">\n";
    for (const auto& run : runs) {
      for (const auto& [x, y] : run) {
        if (!inside(x, y)) continue;
        markerSvg += "<circle cx=\"" + px(x) + "\" cy=\"" + px(y) + "\" r=\"" + r + "\"/>\n";
      }
    }
    markerSvg += "</g>\n";
  }
  o += lineSvg + "</g>\n" + markerSvg + "</g>\n";

  for (const auto& [y, label] : refLabels) {
    const double ty = y - 6 < plotT + kTickFont + 2 ? y + kTickFont + 4 : y - 6;
    o += "<text x=\"" + px(plotR - 6) + "\" y=\"" + px(ty) +
         "\" text-anchor=\"end\" fill=\"#333333\" stroke=\"white\" stroke-width=\"4\" "
         "stroke-linejoin=\"round\" paint-order=\"stroke\">" +
         escapeXml(label) + "</text>\n";
  }

  // Frame, ticks and tick labels.
  o += "<rect x=\"" + px(plotL) + "\" y=\"" + px(plotT) + "\" width=\"" + px(plotW) +
       "\" height=\"" + px(plotH) +
       "\" fill=\"none\" stroke=\"#333333\" stroke-width=\"1\" shape-rendering=\"crispEdges\"/>\n";
  o += "<g stroke=\"#333333\" stroke-width=\"1\" shape-rendering=\"crispEdges\">\n";
  for (const Tick& t : xTicks) {
    const std::string x = px(sx(t.value));
    o += "<line x1=\"" + x + "\" x2=\"" + x + "\" y1=\"" + px(plotB) + "\" y2=\"" +
         px(plotB + (t.major ? 6 : 3)) + "\"/>\n";
  }
  for (const Tick& t : yTicks) {
    const std::string y = px(sy(t.value));
    o += "<line x1=\"" + px(plotL - (t.major ? 6 : 3)) + "\" x2=\"" + px(plotL) + "\" y1=\"" + y +
         "\" y2=\"" + y + "\"/>\n";
  }
  o += "</g>\n<g fill=\"#222222\">\n";
  for (const Tick& t : xTicks) {
    if (t.major) o += tickText(t, sx(t.value), plotB + 10 + kTickFont, "middle");
  }
  for (const Tick& t : yTicks) {
    if (t.major) o += tickText(t, plotL - 10, sy(t.value) + kTickFont * 0.35, "end");
  }
  o += "</g>\n";

  // Axis labels and title.
  if (!chart.xLabel.empty()) {
    o += "<text x=\"" + px((plotL + plotR) / 2) + "\" y=\"" + px(plotB + 30 + kLabelFont) +
         "\" text-anchor=\"middle\" font-size=\"" + px(kLabelFont) + "\" fill=\"#111111\">" +
         escapeXml(chart.xLabel) + "</text>\n";
  }
  if (!chart.yLabel.empty()) {
    const double x = 12 + kLabelFont * 0.85, y = (plotT + plotB) / 2;
    o += "<text x=\"" + px(x) + "\" y=\"" + px(y) + "\" transform=\"rotate(-90 " + px(x) + " " +
         px(y) + ")\" text-anchor=\"middle\" font-size=\"" + px(kLabelFont) +
         "\" fill=\"#111111\">" + escapeXml(chart.yLabel) + "</text>\n";
  }
  if (!chart.title.empty()) {
    const double half = textWidth(chart.title, kTitleFont) / 2;
    const double cx = std::clamp((plotL + plotR) / 2, std::min(half + 8, totalW / 2),
                                 std::max(totalW - half - 8, totalW / 2));
    o += "<text x=\"" + px(cx) + "\" y=\"30\" text-anchor=\"middle\" font-size=\"" +
         px(kTitleFont) + "\" font-weight=\"bold\" fill=\"#111111\">" + escapeXml(chart.title) +
         "</text>\n";
  }

  // Legend column to the right of the plot area.
  if (legendRows > 0) {
    o += "<rect x=\"" + px(legendX) + "\" y=\"" + px(plotT) + "\" width=\"" + px(legendW) +
         "\" height=\"" + px(legendH) +
         "\" rx=\"3\" fill=\"white\" stroke=\"#bbbbbb\" stroke-width=\"1\"/>\n";
    double rowY = plotT + 10 + kRow / 2;
    for (std::size_t si = 0; si < chart.series.size(); ++si) {
      const Series& s = chart.series[si];
      if (s.label.empty()) continue;
      const std::string color = escapeXml(colors[si]);
      const double sx0 = legendX + 12, sx1 = sx0 + kSample;
      if (s.lines) {
        o += "<line x1=\"" + px(sx0) + "\" x2=\"" + px(sx1) + "\" y1=\"" + px(rowY) + "\" y2=\"" +
             px(rowY) + "\" stroke=\"" + color + "\" stroke-width=\"2\"";
        if (!s.dash.empty()) o += " stroke-dasharray=\"" + escapeXml(s.dash) + "\"";
        o += "/>\n";
      }
      o += "<circle cx=\"" + px((sx0 + sx1) / 2) + "\" cy=\"" + px(rowY) + "\" r=\"" +
           (s.lines ? "3.2" : "4.2") + "\" fill=\"" + color + "\" stroke=\"white\"/>\n";
      o += "<text x=\"" + px(sx1 + 10) + "\" y=\"" + px(rowY + kLegendFont * 0.35) +
           "\" font-size=\"" + px(kLegendFont) + "\" fill=\"#222222\">" + escapeXml(s.label) +
           "</text>\n";
      rowY += kRow;
    }
  }
  o += "</svg>\n";
  return o;
}

// Writes "<path>.tmp" and renames it over path, so a failed write leaves no partial file.
inline bool writeSvg(const Chart& chart, const std::filesystem::path& path) {
  const std::string text = renderSvg(chart);
  std::filesystem::path tmp = path;
  tmp += ".tmp";
  std::error_code ec;
  {
    std::ofstream out(tmp, std::ios::binary | std::ios::trunc);
    if (!out) return false;
    out.write(text.data(), static_cast<std::streamsize>(text.size()));
    out.close();
    if (out.fail()) {
      std::filesystem::remove(tmp, ec);
      return false;
    }
  }
  std::filesystem::rename(tmp, path, ec);
  if (ec) {
    std::filesystem::remove(tmp, ec);
    return false;
  }
  return true;
}

}  // namespace compose::bench
