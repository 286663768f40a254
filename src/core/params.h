// ParamSet: named parameters for things created by name (lighting bases, later stages), in the
// manner of pbrt's ParameterDictionary. Values arrive as text ("order=2,window=hanning" on the
// command line); a creator reads what it understands, and unusedNames() reports the rest so that a
// misspelt parameter is an error instead of being silently ignored.
#pragma once

#include <charconv>
#include <cmath>
#include <map>
#include <string>
#include <vector>

#include "core/error.h"

namespace compose {

class ParamSet {
 public:
  ParamSet() = default;

  // Parses "key=value,key=value". Throws compose::Error (stage `stage`) on malformed text and on a
  // key given twice (which of the two was meant cannot be known).
  static ParamSet parse(const std::string& text, const std::string& stage) {
    ParamSet p;
    if (text.empty()) return p;
    // Every piece between commas is a parameter: "order=2," holds an empty one after the comma.
    size_t start = 0;
    for (;;) {
      size_t end = text.find(',', start);
      if (end == std::string::npos) end = text.size();
      const std::string item = text.substr(start, end - start);
      const size_t eq = item.find('=');
      if (item.empty()) {
        throw Error(stage, "malformed parameters '" + text + "': an empty one " +
                               (end == text.size() ? "after the last comma"
                                : start == 0       ? "before the first comma"
                                                   : "between commas"));
      }
      if (eq == std::string::npos || eq == 0) {
        throw Error(stage, "malformed parameter '" + item + "', expected key=value");
      }
      const std::string key = item.substr(0, eq);
      if (p.has(key)) throw Error(stage, "parameter '" + key + "' is given twice");
      p.set(key, item.substr(eq + 1));
      if (end == text.size()) return p;
      start = end + 1;
    }
  }

  void set(const std::string& key, const std::string& value) { values_[key] = Entry{value, false}; }
  bool has(const std::string& key) const { return values_.count(key) != 0; }
  // Whether `key` is given as exactly `value`, without reading it: a parameter looked at this way
  // still counts as unused for requireAllUsed().
  bool is(const std::string& key, const std::string& value) const {
    const auto it = values_.find(key);
    return it != values_.end() && it->second.value == value;
  }
  void erase(const std::string& key) { values_.erase(key); }

  int getInt(const std::string& key, int fallback, const std::string& stage) {
    auto it = values_.find(key);
    if (it == values_.end()) return fallback;
    it->second.used = true;
    int v = 0;
    const std::string& s = it->second.value;
    auto [ptr, ec] = std::from_chars(s.data(), s.data() + s.size(), v);
    if (ec != std::errc() || ptr != s.data() + s.size()) {
      throw Error(stage, "parameter " + key + "='" + s + "' is not an integer");
    }
    return v;
  }

  // A finite number: "nan", "inf" and out-of-range values are errors.
  double getDouble(const std::string& key, double fallback, const std::string& stage) {
    auto it = values_.find(key);
    if (it == values_.end()) return fallback;
    it->second.used = true;
    const std::string& s = it->second.value;
    double v = 0.0;
    try {
      size_t n = 0;
      v = std::stod(s, &n);
      if (n != s.size()) throw std::invalid_argument(s);
    } catch (const std::exception&) {
      throw Error(stage, "parameter " + key + "='" + s + "' is not a number");
    }
    if (!std::isfinite(v)) throw Error(stage, "parameter " + key + "='" + s + "' is not finite");
    return v;
  }

  std::string getString(const std::string& key, const std::string& fallback) {
    auto it = values_.find(key);
    if (it == values_.end()) return fallback;
    it->second.used = true;
    return it->second.value;
  }

  std::vector<std::string> unusedNames() const {
    std::vector<std::string> out;
    for (const auto& [k, e] : values_) {
      if (!e.used) out.push_back(k);
    }
    return out;
  }

  // Throws if any parameter was never read by whoever consumed this set.
  void requireAllUsed(const std::string& stage, const std::string& consumer) const {
    const auto unused = unusedNames();
    if (unused.empty()) return;
    std::string list;
    for (const auto& k : unused) list += (list.empty() ? "" : ", ") + k;
    throw Error(stage, consumer + " does not take parameter(s): " + list);
  }

 private:
  struct Entry {
    std::string value;
    bool used = false;
  };
  std::map<std::string, Entry> values_;
};

}  // namespace compose
