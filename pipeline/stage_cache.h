// StageCache: one stage's outputs kept on disk under their key, so that a later run with the same
// inputs and parameters reloads them instead of computing them again.
//
// An entry is one file, <folder>/<stage>/<key>.stage: an 8-byte magic (7 bytes naming the kind,
// the last the format version), the length of a JSON header, the header (the stage, the key, the
// stage's own metadata, and the name and length of every float array), the arrays' floats, and a
// 128-bit checksum of the header and the floats. Entries are written to a temporary file (unique
// per process and write) and renamed into place, so a reader never sees a half-written one and
// any number of runs may share one folder: the last complete write wins.
//
// open() checks every field against the bytes actually present before allocating anything: an
// entry that is empty, truncated, zeroed, of another format version, of another stage or key,
// whose header does not parse, whose sizes do not add up or whose checksum fails is *invalid*:
// open() returns false and problem() says what is wrong, so that the runner can tell the user
// (the stage then runs and its store() rewrites the entry). A missing entry is a plain miss
// (problem() empty). Nothing here throws on a bad entry: a cache that cannot be read or written
// only costs time; write() failing leaves the reason in error().
#pragma once

#include <filesystem>
#include <map>
#include <span>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "core/image.h"

namespace compose::pipeline {

class StageCache {
 public:
  // An empty folder: no cache (exists() and open() are false, write() does nothing).
  StageCache(std::filesystem::path folder, std::string stage, std::string key);
  // A stage file a user names (compose precompute --out): the same format at that path, opened
  // whatever key it was written under.
  static StageCache atFile(std::filesystem::path file, std::string stage);

  const std::filesystem::path& path() const { return path_; }
  bool enabled() const { return !path_.empty(); }
  bool exists() const;

  // Reads the whole entry; false on a miss or an invalid entry (problem() says what is wrong).
  bool open();
  // open(), keeping nothing of the entry's contents: whether it would open.
  bool verify();
  // The stage's meta as the entry's header holds it, without reading or checking the arrays: for
  // what the entry says (its notes), never for its outputs. Null on a miss or a wrong header.
  nlohmann::json peekMeta() const;
  // Forgets what open() read (the header's meta and the arrays), for an entry to be written anew.
  void clear();
  // Writes the entry atomically; false (nothing left behind) if it could not be written, with the
  // operating system's reason in error() ("Permission denied", "No space left on device").
  bool write() const;
  const std::string& error() const { return error_; }
  const std::string& key() const { return key_; }
  // What was wrong with the entry the last open() found; empty after a success or a plain miss
  // (no entry).
  const std::string& problem() const { return problem_; }

  // The stage's own fields; a store adds to it (the runner keeps the notes of the stage's run
  // under "notes").
  nlohmann::json& meta() { return meta_; }
  const nlohmann::json& meta() const { return meta_; }

  void put(const std::string& name, std::span<const float> values);
  void put(const std::string& name, Pixels&& values);
  // The array of that name (empty if there is none).
  std::span<const float> get(const std::string& name) const;

  // An image: its size, channel names and colour space in the header, its pixels as an array.
  void putImage(const std::string& name, const Image& image);
  bool getImage(const std::string& name, Image& image) const;
  // The same, moving the pixels out of the entry instead of copying them (the entry's array is
  // left empty): a large image is then held once, not twice.
  bool takeImage(const std::string& name, Image& image);

 private:
  std::filesystem::path path_;
  std::string stage_, key_;
  bool anyKey_ = false;
  mutable std::string error_;
  nlohmann::json meta_ = nlohmann::json::object();
  std::map<std::string, Pixels> arrays_;

  // The image of that name with its size, names and colour space but no pixels, and the array
  // that holds them; nullptr if there is none or it does not fit.
  const Pixels* imageWithoutPixels(const std::string& name, Image& image) const;
  mutable std::string problem_;
};

}  // namespace compose::pipeline
