#include "core/entry_file.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>

namespace compose {

bool readFullyAt(int fd, void* to, size_t n, uint64_t at) {
  char* p = static_cast<char*>(to);
  while (n > 0) {
    const ssize_t got = ::pread(fd, p, n, off_t(at));
    if (got < 0 && errno == EINTR) continue;
    if (got <= 0) {
      if (got == 0) errno = 0;
      return false;
    }
    p += got;
    at += uint64_t(got);
    n -= size_t(got);
  }
  return true;
}

EntryFile::EntryFile(const std::filesystem::path& path)
    : fd_(::open(path.c_str(), O_RDONLY | O_CLOEXEC | O_NONBLOCK)) {}

EntryFile::~EntryFile() {
  if (fd_ >= 0) ::close(fd_);
}

bool EntryFile::stat(uint64_t& size, bool& regular) const {
  struct stat st {};
  if (::fstat(fd_, &st) != 0) return false;
  size = uint64_t(st.st_size);
  regular = S_ISREG(st.st_mode);
  return true;
}

}  // namespace compose
