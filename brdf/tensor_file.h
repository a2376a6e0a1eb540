// The "tensor file" container of the RGL-EPFL material database (Dupuy &
// Jakob 2018, "An Adaptive Parameterization for Efficient Material
// Acquisition and Rendering"), as read by Mitsuba 3 and the authors' loaders.
//
// Layout, little-endian: bytes 0-11 "tensor_file\0"; bytes 12-13 uint8
// version 1, 0; bytes 14-17 uint32 field count; then per field: uint16 name
// length, the name (no NUL), uint16 ndim, uint8 dtype, uint64 absolute offset
// of the data, ndim x uint64 shape. Each field's data is contiguous at its
// offset in C order (last index fastest). dtype codes: 1 u8, 2 i8, 3 u16,
// 4 i16, 5 u32, 6 i32, 7 u64, 8 i64, 9 f16, 10 f32, 11 f64. The writer
// aligns every data block to 8 bytes, as the authors' Python writer does.
#pragma once

#include "brdf/atomic_file.h"

#include <algorithm>
#include <bit>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <limits>
#include <stdexcept>
#include <string>
#include <vector>

namespace brdfkit {

class TensorFile {
 public:
  enum DType : std::uint8_t {
    kU8 = 1, kI8, kU16, kI16, kU32, kI32, kU64, kI64, kF16, kF32, kF64
  };

  struct Field {
    std::string name;
    std::uint8_t dtype = kF32;
    std::vector<std::uint64_t> shape;
    std::vector<unsigned char> bytes;  // little-endian, C order

    std::uint64_t Count() const {
      std::uint64_t n = 1;
      for (std::uint64_t s : shape) n *= s;
      return n;
    }
  };

  std::vector<Field> fields;

  static std::size_t DTypeSize(std::uint8_t dtype) {
    static constexpr std::size_t kSize[12] = {0, 1, 1, 2, 2, 4, 4, 8, 8, 2, 4, 8};
    return dtype >= 1 && dtype <= 11 ? kSize[dtype] : 0;
  }
  static std::string DTypeName(std::uint8_t dtype) {
    static const char* kName[12] = {"?", "uint8", "int8", "uint16", "int16", "uint32", "int32",
                                    "uint64", "int64", "float16", "float32", "float64"};
    return dtype >= 1 && dtype <= 11 ? kName[dtype] : "unknown dtype " + std::to_string(int(dtype));
  }

  const Field* Find(const std::string& name) const {
    for (const Field& f : fields)
      if (f.name == name) return &f;
    return nullptr;
  }

  void Add(const std::string& name, const std::vector<float>& values, std::vector<std::uint64_t> shape) {
    Field f{name, kF32, std::move(shape), std::vector<unsigned char>(values.size() * 4)};
    for (std::size_t i = 0; i < values.size(); ++i) {
      const std::uint32_t u = std::bit_cast<std::uint32_t>(values[i]);
      for (int b = 0; b < 4; ++b) f.bytes[4 * i + b] = static_cast<unsigned char>(u >> (8 * b));
    }
    fields.push_back(std::move(f));
  }
  void Add(const std::string& name, const std::vector<unsigned char>& values) {
    fields.push_back(Field{name, kU8, {values.size()}, values});
  }

  // float32 values of a field (little-endian decode, any host).
  static std::vector<float> Floats(const Field& f) {
    std::vector<float> out(f.bytes.size() / 4);
    for (std::size_t i = 0; i < out.size(); ++i) {
      std::uint32_t u = 0;
      for (int b = 0; b < 4; ++b) u |= std::uint32_t(f.bytes[4 * i + b]) << (8 * b);
      out[i] = std::bit_cast<float>(u);
    }
    return out;
  }

  // Throws std::runtime_error naming the file and the field: no such file,
  // wrong magic or version, a field table or a data block past the end,
  // unknown dtypes, shapes whose size overflows.
  static TensorFile Read(const std::string& path) {
    namespace fs = std::filesystem;
    const std::string what = "tensor file '" + path + "'";
    std::error_code ec;
    const fs::file_status st = fs::status(path, ec);
    if (!fs::exists(st)) throw std::runtime_error("cannot read " + what + ": no such file");
    if (fs::is_directory(st)) throw std::runtime_error("cannot read " + what + ": it is a directory");
    std::ifstream in(path, std::ios::binary);
    if (!in) throw std::runtime_error("cannot open " + what);
    const std::vector<unsigned char> buf((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    return Parse(buf, what);
  }

  static TensorFile Parse(const std::vector<unsigned char>& buf, const std::string& what) {
    std::size_t pos = 0;
    auto need = [&](std::size_t n, const std::string& field) {
      if (n > buf.size() || pos > buf.size() - n)
        throw std::runtime_error(what + " is truncated: " + field + " at byte " + std::to_string(pos) +
                                 " runs past the end (" + std::to_string(buf.size()) + " bytes)");
    };
    auto uint = [&](int bytes, const std::string& field) {
      need(bytes, field);
      std::uint64_t v = 0;
      for (int b = 0; b < bytes; ++b) v |= std::uint64_t(buf[pos + b]) << (8 * b);
      pos += bytes;
      return v;
    };
    static const char kMagic[12] = {'t', 'e', 'n', 's', 'o', 'r', '_', 'f', 'i', 'l', 'e', '\0'};
    need(12, "the magic");
    if (std::memcmp(buf.data(), kMagic, 12) != 0)
      throw std::runtime_error(what + " does not start with the magic \"tensor_file\\0\" (not a tensor file)");
    pos = 12;
    const auto major = uint(1, "the version"), minor = uint(1, "the version");
    if (major != 1 || minor != 0)
      throw std::runtime_error(what + " has version " + std::to_string(major) + "." + std::to_string(minor) +
                               ", expected 1.0");
    const std::uint64_t count = uint(4, "the field count");
    // Every field entry takes at least 13 bytes: a count beyond that is corrupt.
    if (count > (buf.size() - pos) / 13)
      throw std::runtime_error(what + " claims " + std::to_string(count) + " fields, more than its " +
                               std::to_string(buf.size()) + " bytes can hold");
    TensorFile t;
    for (std::uint64_t k = 0; k < count; ++k) {
      const std::string entry = "field " + std::to_string(k);
      const std::size_t len = uint(2, entry + " name length");
      need(len, entry + " name");
      Field f;
      f.name.assign(reinterpret_cast<const char*>(buf.data() + pos), len);
      pos += len;
      const std::string label = "field '" + f.name + "'";
      if (t.Find(f.name)) throw std::runtime_error(what + ": " + label + " appears twice");
      const std::size_t ndim = uint(2, label + " ndim");
      f.dtype = static_cast<std::uint8_t>(uint(1, label + " dtype"));
      if (DTypeSize(f.dtype) == 0)
        throw std::runtime_error(what + ": " + label + " has " + DTypeName(f.dtype) + " (expected 1 to 11)");
      const std::uint64_t offset = uint(8, label + " offset");
      need(8 * ndim, label + " shape");
      std::uint64_t bytes = DTypeSize(f.dtype);
      for (std::size_t d = 0; d < ndim; ++d) {
        const std::uint64_t s = uint(8, label + " shape");
        f.shape.push_back(s);
        if (s != 0 && bytes > std::numeric_limits<std::uint64_t>::max() / s)
          throw std::runtime_error(what + ": " + label + " has a shape whose size overflows");
        bytes *= s;
      }
      if (offset > buf.size() || bytes > buf.size() - offset)
        throw std::runtime_error(what + ": " + label + " data (" + std::to_string(bytes) + " bytes at offset " +
                                 std::to_string(offset) + ") runs past the end of the file (" +
                                 std::to_string(buf.size()) + " bytes)");
      f.bytes.assign(buf.begin() + std::ptrdiff_t(offset), buf.begin() + std::ptrdiff_t(offset + bytes));
      t.fields.push_back(std::move(f));
    }
    return t;
  }

  std::vector<unsigned char> Serialise() const {
    std::vector<unsigned char> out(12);
    std::memcpy(out.data(), "tensor_file", 12);
    auto put = [&](std::uint64_t v, int bytes) {
      for (int b = 0; b < bytes; ++b) out.push_back(static_cast<unsigned char>(v >> (8 * b)));
    };
    put(1, 1);
    put(0, 1);
    put(fields.size(), 4);
    std::size_t table = out.size();
    for (const Field& f : fields) table += 2 + f.name.size() + 2 + 1 + 8 + 8 * f.shape.size();
    std::uint64_t offset = (table + 7) / 8 * 8;
    std::vector<std::uint64_t> offsets;
    for (const Field& f : fields) {
      offsets.push_back(offset);
      offset = (offset + f.bytes.size() + 7) / 8 * 8;
      put(f.name.size(), 2);
      out.insert(out.end(), f.name.begin(), f.name.end());
      put(f.shape.size(), 2);
      put(f.dtype, 1);
      put(offsets.back(), 8);
      for (std::uint64_t s : f.shape) put(s, 8);
    }
    for (std::size_t k = 0; k < fields.size(); ++k) {
      out.resize(offsets[k], 0);
      out.insert(out.end(), fields[k].bytes.begin(), fields[k].bytes.end());
    }
    out.resize((out.size() + 7) / 8 * 8, 0);
    return out;
  }

  // Writes atomically: a complete file or nothing.
  void Write(const std::string& path) const {
    const std::vector<unsigned char> bytes = Serialise();
    AtomicFile f(path, std::ios::out | std::ios::binary);
    f.stream().write(reinterpret_cast<const char*>(bytes.data()), std::streamsize(bytes.size()));
    f.Commit();
  }
};

}  // namespace brdfkit
