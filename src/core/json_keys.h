// Keys a JSON object holds twice.
//
// RFC 8259 leaves an object with a repeated name to the reader; nlohmann::json keeps the last
// value and says nothing, so that in a hand-edited file ("scale": 0.2, ..., "scale": 0.5, or two
// "render" blocks) a setting is lost without a word. Our readers of files people edit refuse them.
#pragma once

#include <set>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

namespace compose {

// A reader of JSON events that takes every value and stops at a parse error (the parser says
// why): the readers below override what they look at.
struct JsonEvents : nlohmann::json_sax<nlohmann::json> {
  bool null() override { return true; }
  bool boolean(bool) override { return true; }
  bool number_integer(number_integer_t) override { return true; }
  bool number_unsigned(number_unsigned_t) override { return true; }
  bool number_float(number_float_t, const string_t&) override { return true; }
  bool string(string_t&) override { return true; }
  bool binary(binary_t&) override { return true; }
  bool key(string_t&) override { return true; }
  bool parse_error(std::size_t, const std::string&, const nlohmann::detail::exception&) override {
    return false;
  }
};

// The first key that an object of the JSON `text` holds twice, with the keys that lead to it
// ("stages.render.scale"; an array's elements as "[]"); empty when none, or when `text` is not
// JSON (the parser says why).
inline std::string repeatedJsonKey(const std::string& text) {
  struct Finder : JsonEvents {
    struct Level {
      bool object = false;
      std::set<std::string> keys;
      std::string key;  // the key whose value is being read
    };
    std::vector<Level> levels;
    std::string found;

    std::string path(const std::string& last) const {
      std::string p;
      for (const Level& l : levels) {
        if (&l == &levels.back()) break;
        p += l.object ? (p.empty() ? "" : ".") + l.key : std::string("[]");
      }
      return p + (p.empty() ? "" : ".") + last;
    }
    bool start_object(std::size_t) override {
      levels.push_back({true, {}, {}});
      return true;
    }
    bool key(string_t& k) override {
      Level& l = levels.back();
      if (!l.keys.insert(k).second) {
        found = path(k);
        return false;  // enough: stop reading
      }
      l.key = k;
      return true;
    }
    bool end_object() override {
      levels.pop_back();
      return true;
    }
    bool start_array(std::size_t) override {
      levels.push_back({false, {}, {}});
      return true;
    }
    bool end_array() override {
      levels.pop_back();
      return true;
    }
  } finder;
  nlohmann::json::sax_parse(text, &finder, nlohmann::json::input_format_t::json, false);
  return finder.found;
}

// Files people edit or download nest a few levels deep; nlohmann::json copies and tinygltf reads
// a value recursively, so a hostile file nested a hundred thousand levels deep overflowed the
// stack (a crash, not an error). Readers refuse JSON nested deeper than this.
inline constexpr size_t kMaxJsonDepth = 256;

// Whether the JSON `text` nests objects and arrays more than `limit` deep (read without building
// anything; stops at the first level too many). False for text that is not JSON: the parser says
// why.
inline bool jsonNestedDeeperThan(const std::string& text, size_t limit = kMaxJsonDepth) {
  struct Depth : JsonEvents {
    size_t limit = 0, depth = 0;
    bool deeper = false;
    bool enter() {
      deeper = ++depth > limit;
      return !deeper;
    }
    bool start_object(std::size_t) override { return enter(); }
    bool end_object() override {
      --depth;
      return true;
    }
    bool start_array(std::size_t) override { return enter(); }
    bool end_array() override {
      --depth;
      return true;
    }
  } counter;
  counter.limit = limit;
  nlohmann::json::sax_parse(text, &counter, nlohmann::json::input_format_t::json, false);
  return counter.deeper;
}

}  // namespace compose
