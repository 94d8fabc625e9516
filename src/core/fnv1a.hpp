// FNV-1a, 64 bit (Fowler–Noll–Vo; the prime of the 64-bit variant): the one implementation behind
// the content hashes (Scenario::hash and Sweep::hash, `hash_fnv1a64` in summary.json), the labels
// of the canonical order of expressions (symbolic/canonical.cpp) and CubicSpline::fingerprint().
// Internal (header-only), included as "core/fnv1a.hpp" by the libraries.
#pragma once

#include <cstdint>
#include <string>
#include <string_view>

namespace ukdyn::detail {

/// The offset basis of 64-bit FNV-1a.
inline constexpr std::uint64_t kFnv1a64Basis = 14695981039346656037ull;
/// The basis of ukdyn's content hashes and canonical labels: the standard one with its last digit
/// dropped. Kept as it is: a new basis would change every `hash_fnv1a64` already written (a resumed
/// sweep and `ukdyn replay` compare them) and the canonical order of derived expressions.
inline constexpr std::uint64_t kUkdynHashBasis = 1469598103934665603ull;
inline constexpr std::uint64_t kFnv1a64Prime = 1099511628211ull;

/// Streaming: bytes added in several calls hash as their concatenation.
class Fnv1a64 {
 public:
  constexpr explicit Fnv1a64(std::uint64_t basis = kFnv1a64Basis) : h_(basis) {}

  constexpr Fnv1a64& add(unsigned char byte) {
    h_ ^= byte;
    h_ *= kFnv1a64Prime;
    return *this;
  }
  constexpr Fnv1a64& add(std::string_view bytes) {
    for (const char c : bytes) add(static_cast<unsigned char>(c));
    return *this;
  }
  /// The 8 bytes of x, least significant first.
  constexpr Fnv1a64& add_le64(std::uint64_t x) {
    for (int i = 0; i < 8; ++i, x >>= 8) add(static_cast<unsigned char>(x & 0xffU));
    return *this;
  }

  [[nodiscard]] constexpr std::uint64_t value() const { return h_; }
  /// value() as 16 lower-case hex digits.
  [[nodiscard]] std::string hex() const {
    std::string s(16, '0');
    std::uint64_t v = h_;
    for (std::size_t i = 16; i-- > 0; v >>= 4) s[i] = "0123456789abcdef"[v & 0xfU];
    return s;
  }

 private:
  std::uint64_t h_;
};

/// A content hash of ukdyn (kUkdynHashBasis) of some bytes.
constexpr std::uint64_t ukdyn_hash(std::string_view bytes) {
  return Fnv1a64(kUkdynHashBasis).add(bytes).value();
}

}  // namespace ukdyn::detail
