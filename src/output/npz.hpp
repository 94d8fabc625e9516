// Internal to ukdyn::io: numpy's .npz (a zip archive of .npy files), written uncompressed.
// .npy format version 1.0 (numpy's "NEP 1 — A simple file format for NumPy arrays"): the magic
// "\x93NUMPY", version 1.0, a little-endian uint16 header length, an ASCII dict
// {'descr': '<f8', 'fortran_order': False, 'shape': (...), } padded with spaces and a newline so
// that the data start at a multiple of 64 bytes, then the data in C (row-major) order. The zip
// container (PKWARE APPNOTE.TXT 6.3.x): one local file header + data per entry, "stored" (method
// 0, no compression) with its CRC-32 (the reflected polynomial 0xEDB88320), then the central
// directory and its end record; no ZIP64 (entries and archive under 4 GiB).
#pragma once

#include <cstdint>
#include <string>
#include <vector>

namespace ukdyn::io_detail {

/// One float64 array: its shape (empty: a scalar) and its values in row-major order.
struct NpyArray {
  std::string name;  ///< the key numpy.load gives it (the entry is name + ".npy")
  std::vector<std::size_t> shape;
  std::vector<double> values;
};

/// CRC-32 of the zip format (ISO 3309 / ITU-T V.42, as zlib's crc32).
std::uint32_t crc32(const std::string& bytes);

/// The .npy bytes of one array (version 1.0, '<f8').
std::string npy_bytes(const NpyArray& a);

/// The .npz archive of the arrays (uncompressed, as numpy.savez writes it).
std::string npz_bytes(const std::vector<NpyArray>& arrays);

}  // namespace ukdyn::io_detail
