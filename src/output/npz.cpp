// numpy .npz writer (src/output/npz.hpp): .npy 1.0 entries in an uncompressed zip archive.
#include "output/npz.hpp"

#include <array>
#include <bit>
#include <cstring>
#include <stdexcept>

namespace ukdyn::io_detail {

namespace {

void put16(std::string& s, std::uint32_t v) {
  s.push_back(static_cast<char>(v & 0xffu));
  s.push_back(static_cast<char>((v >> 8) & 0xffu));
}

void put32(std::string& s, std::uint32_t v) {
  put16(s, v & 0xffffu);
  put16(s, v >> 16);
}

std::uint32_t checked32(std::size_t v) {
  if (v > 0xffffffffu) throw std::length_error("npz: an entry or the archive exceeds 4 GiB");
  return static_cast<std::uint32_t>(v);
}

// The fields a local header and a central-directory entry share (APPNOTE 4.3.7, 4.3.12): version
// needed 2.0, no flags, method 0 (stored), time/date 0 (1980-01-01), CRC, sizes, name length.
void common_fields(std::string& s, std::uint32_t crc, std::uint32_t size, std::size_t name_len) {
  put16(s, 20);
  put16(s, 0);
  put16(s, 0);
  put16(s, 0);
  put16(s, 0x21);  // 1980-01-01
  put32(s, crc);
  put32(s, size);
  put32(s, size);
  put16(s, checked32(name_len));
}

}  // namespace

std::uint32_t crc32(const std::string& bytes) {
  std::array<std::uint32_t, 256> table{};
  for (std::uint32_t i = 0; i < 256; ++i) {
    std::uint32_t c = i;
    for (int k = 0; k < 8; ++k) c = (c & 1u) ? 0xEDB88320u ^ (c >> 1) : c >> 1;
    table[i] = c;
  }
  std::uint32_t c = 0xffffffffu;
  for (unsigned char b : bytes) c = table[(c ^ b) & 0xffu] ^ (c >> 8);
  return c ^ 0xffffffffu;
}

std::string npy_bytes(const NpyArray& a) {
  static_assert(std::endian::native == std::endian::little, "npy: '<f8' written as in memory");
  // The shape as Python writes a tuple: (), (n,), (a, b).
  std::size_t count = 1;
  std::string shape = "(";
  for (std::size_t k = 0; k < a.shape.size(); ++k) {
    shape += (k > 0 ? ", " : "") + std::to_string(a.shape[k]);
    count *= a.shape[k];
  }
  shape += a.shape.size() == 1 ? ",)" : ")";
  if (count != a.values.size()) throw std::invalid_argument("npy: shape and values differ");
  std::string header = "{'descr': '<f8', 'fortran_order': False, 'shape': " + shape + ", }";
  const std::size_t unpadded = 10 + header.size() + 1;  // magic, version, length; '\n'
  header.append((64 - unpadded % 64) % 64, ' ');
  header.push_back('\n');
  std::string s = "\x93NUMPY";
  s.push_back('\x01');
  s.push_back('\x00');
  put16(s, checked32(header.size()));
  s += header;
  const std::size_t at = s.size();
  s.resize(at + count * sizeof(double));
  if (count > 0) std::memcpy(s.data() + at, a.values.data(), count * sizeof(double));
  return s;
}

std::string npz_bytes(const std::vector<NpyArray>& arrays) {
  std::string out, central;
  for (const auto& a : arrays) {
    const std::string name = a.name + ".npy", data = npy_bytes(a);
    const std::uint32_t crc = crc32(data), size = checked32(data.size()),
                        offset = checked32(out.size());
    put32(out, 0x04034b50u);  // local file header (APPNOTE 4.3.7)
    common_fields(out, crc, size, name.size());
    put16(out, 0);  // extra field length
    out += name;
    out += data;
    put32(central, 0x02014b50u);  // central directory file header (4.3.12)
    put16(central, 20);           // version made by
    common_fields(central, crc, size, name.size());
    put16(central, 0);  // extra field length
    put16(central, 0);  // comment length
    put16(central, 0);  // disk number start
    put16(central, 0);  // internal attributes
    put32(central, 0);  // external attributes
    put32(central, offset);
    central += name;
  }
  const std::uint32_t cd_offset = checked32(out.size()), cd_size = checked32(central.size());
  out += central;
  put32(out, 0x06054b50u);  // end of central directory record (4.3.16)
  put16(out, 0);
  put16(out, 0);
  put16(out, checked32(arrays.size()));
  put16(out, checked32(arrays.size()));
  put32(out, cd_size);
  put32(out, cd_offset);
  put16(out, 0);
  checked32(out.size());
  return out;
}

}  // namespace ukdyn::io_detail
