// A cache entry opened for reading by offset: one descriptor for the whole entry, so that a
// writer replacing the file meanwhile (by rename) cannot mix two entries' bytes. Opened
// non-blocking, so that a FIFO or device where an entry should be is refused, not waited on.
#pragma once

#include <cstddef>
#include <cstdint>
#include <filesystem>

namespace compose {

// Reads exactly n bytes of `fd` at byte `at` (pread, retried after EINTR and short reads). False
// on an error (errno says which) or when the file ends first (errno 0).
bool readFullyAt(int fd, void* to, size_t n, uint64_t at);

class EntryFile {
 public:
  explicit EntryFile(const std::filesystem::path& path);
  ~EntryFile();
  EntryFile(const EntryFile&) = delete;
  EntryFile& operator=(const EntryFile&) = delete;

  // False when the file could not be opened (errno says why).
  bool isOpen() const { return fd_ >= 0; }
  int fd() const { return fd_; }
  // Fills `size` and `regular` (a regular file) from fstat; false on an error (errno says why).
  bool stat(uint64_t& size, bool& regular) const;
  bool readAt(void* to, size_t n, uint64_t at) const { return readFullyAt(fd_, to, n, at); }

 private:
  int fd_ = -1;
};

}  // namespace compose
