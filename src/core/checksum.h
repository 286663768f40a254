// Checksums of large float arrays (cache entries of hundreds of megabytes), fast enough that
// checking an entry costs far less than reading it.
#pragma once

#include <span>

#include "core/hash.h"

namespace compose {

// A 128-bit checksum of `values`, bit for bit: blocks of 2^18 values are hashed on every core,
// each as four interleaved Hash128 streams (independent multiply chains, so that one core keeps
// several in flight), and the blocks' hashes are combined in order with the count. Deterministic
// whatever the thread count; not the value Hash128::floats gives.
Hash128 checksumFloats(std::span<const float> values);

}  // namespace compose
