// Checksums of large float arrays (cache entries of hundreds of megabytes), fast enough that
// checking an entry costs far less than reading it.
#pragma once

#include <cstdint>
#include <optional>
#include <span>

#include "core/hash.h"

namespace compose {

// A 128-bit checksum of `values`, bit for bit: blocks of 2^18 values are hashed on every core,
// each as four interleaved streams of 64-bit words (independent multiply chains, so that one core
// keeps several in flight), and the blocks' hashes are combined in order with the count.
// Deterministic whatever the thread count; not the value Hash128::floats gives.
Hash128 checksumFloats(std::span<const float> values);

// Reads values.size() floats from the open file `fd`, starting at byte `offset`, into `values`,
// and returns their checksumFloats(). The blocks are read (pread) and hashed on every core, each
// hashed as soon as it is read, while it is still in the processor's cache. Empty when the file
// cannot be read or ends first (errno tells why; 0 for a short file).
std::optional<Hash128> readChecksummedFloats(int fd, uint64_t offset, std::span<float> values);

}  // namespace compose
