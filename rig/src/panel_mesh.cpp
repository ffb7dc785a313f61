#include "markcell/rig/panel_mesh.hpp"

#include <embree3/rtcore.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <sstream>
#include <stdexcept>

#include <assimp/Importer.hpp>
#include <assimp/postprocess.h>
#include <assimp/scene.h>

#include "markcell/common/bounded_file.hpp"

namespace markcell::rig {

namespace {

[[noreturn]] void refuse(const std::string& path, const std::string& what) { throw std::runtime_error(path + ": " + what); }

// PLY, read here rather than by assimp: assimp 5.2.5's PLY reader never returns on a
// header without end_header and crashes on a body cut short (measured on truncated copies
// of config/panels/fender.ply), and a mesh file comes from outside. This reader takes
// ascii and binary (either byte order) PLY 1.0, `vertex` elements with x, y, z of any
// scalar type, `face` elements with a list of vertex indices (a polygon is cut into a
// fan of triangles), skips every other property and element, and checks every count
// against the bytes there are.
constexpr std::uint64_t kMaxPlyElementCount = 3 * kMaxMeshTriangles;

class PlyReader {
 public:
  PlyReader(const std::string& path, const std::string& bytes) : path_(path), bytes_(bytes) {}

  TriangleMesh read(double scale) {
    header();
    TriangleMesh mesh;
    for (const Element& e : elements_) {
      for (std::uint64_t i = 0; i < e.count; ++i) {
        if (e.name == "vertex") {
          Eigen::Vector3d v = Eigen::Vector3d::Zero();
          for (const Property& p : e.properties) {
            if (p.list) {
              skip_list(p);
              continue;
            }
            const double x = scalar(p.type);
            if (p.name == "x") v.x() = x;
            if (p.name == "y") v.y() = x;
            if (p.name == "z") v.z() = x;
          }
          v *= scale;
          if (!v.allFinite()) refuse(path_, "vertex " + std::to_string(i) + " is not a finite number");
          mesh.vertices.push_back(v);
        } else if (e.name == "face") {
          for (const Property& p : e.properties) {
            if (!p.list || (p.name != "vertex_indices" && p.name != "vertex_index")) {
              if (p.list) skip_list(p);
              else scalar(p.type);
              continue;
            }
            const double n = scalar(p.count_type);
            if (!(n >= 0) || n > 1024) refuse(path_, "face " + std::to_string(i) + " has " + std::to_string(n) + " corners");
            const auto corners = static_cast<std::size_t>(n);
            std::uint32_t first = 0, previous = 0;
            for (std::size_t k = 0; k < corners; ++k) {
              const double index = scalar(p.type);
              if (!(index >= 0) || index >= static_cast<double>(vertex_count_) || index != std::floor(index))
                refuse(path_, "face " + std::to_string(i) + " names vertex " + std::to_string(index) + " of " +
                                  std::to_string(vertex_count_));
              const auto v = static_cast<std::uint32_t>(index);
              if (k == 0) first = v;
              if (k >= 2) {
                if (mesh.triangles.size() >= kMaxMeshTriangles)
                  refuse(path_, "more than " + std::to_string(kMaxMeshTriangles) + " triangles");
                mesh.triangles.push_back({first, previous, v});
              }
              previous = v;
            }
          }
        } else {
          for (const Property& p : e.properties) {
            if (p.list) skip_list(p);
            else scalar(p.type);
          }
        }
      }
    }
    return mesh;
  }

 private:
  enum class Format { kAscii, kLittle, kBig };
  struct Property {
    std::string name;
    bool list = false;
    std::string count_type, type;
  };
  struct Element {
    std::string name;
    std::uint64_t count = 0;
    std::vector<Property> properties;
  };

  static int size_of(const std::string& t) {
    if (t == "char" || t == "uchar" || t == "int8" || t == "uint8") return 1;
    if (t == "short" || t == "ushort" || t == "int16" || t == "uint16") return 2;
    if (t == "int" || t == "uint" || t == "float" || t == "int32" || t == "uint32" || t == "float32") return 4;
    if (t == "double" || t == "float64") return 8;
    return 0;
  }

  std::string line() {
    const std::size_t end = bytes_.find('\n', pos_);
    if (end == std::string::npos) refuse(path_, "PLY header without end_header");
    std::string l = bytes_.substr(pos_, end - pos_);
    pos_ = end + 1;
    ++line_;
    if (!l.empty() && l.back() == '\r') l.pop_back();
    return l;
  }

  void header() {
    if (line() != "ply") refuse(path_, "not a PLY file (its first line is not 'ply')");
    bool format = false;
    for (;;) {
      if (line_ > 1000) refuse(path_, "PLY header longer than 1000 lines");
      std::istringstream in(line());
      std::string word;
      in >> word;
      const std::string where = "PLY header line " + std::to_string(line_) + ": ";
      if (word == "end_header") break;
      if (word == "comment" || word == "obj_info" || word.empty()) continue;
      if (word == "format") {
        std::string f, version;
        in >> f >> version;
        if (version != "1.0") refuse(path_, where + "format version '" + version + "', only 1.0 is read");
        if (f == "ascii") format_ = Format::kAscii;
        else if (f == "binary_little_endian") format_ = Format::kLittle;
        else if (f == "binary_big_endian") format_ = Format::kBig;
        else refuse(path_, where + "unknown format '" + f + "'");
        format = true;
      } else if (word == "element") {
        Element e;
        if (!(in >> e.name >> e.count)) refuse(path_, where + "expected 'element NAME COUNT'");
        // Each count bounded before any sum: the sums below cannot wrap, and an element
        // without properties (which reads no bytes) cannot loop for 2^64 entries.
        if (e.count > kMaxPlyElementCount)
          refuse(path_, where + std::to_string(e.count) + " " + e.name + " entries, more than " +
                            std::to_string(kMaxPlyElementCount));
        if (elements_.size() >= 64) refuse(path_, where + "more than 64 elements");
        if (e.name == "vertex") vertex_count_ += e.count;
        elements_.push_back(e);
      } else if (word == "property") {
        if (elements_.empty()) refuse(path_, where + "a property before any element");
        Property p;
        in >> p.type;
        if (p.type == "list") {
          p.list = true;
          in >> p.count_type >> p.type;
          if (size_of(p.count_type) == 0 || p.count_type == "float" || p.count_type == "double")
            refuse(path_, where + "list count type '" + p.count_type + "'");
        }
        if (size_of(p.type) == 0) refuse(path_, where + "unknown property type '" + p.type + "'");
        if (!(in >> p.name)) refuse(path_, where + "property without a name");
        if (elements_.back().properties.size() >= 64) refuse(path_, where + "more than 64 properties in one element");
        elements_.back().properties.push_back(p);
      } else {
        refuse(path_, where + "unknown keyword '" + word + "'");
      }
    }
    if (!format) refuse(path_, "PLY header without a format line");
    for (const Element& e : elements_) {
      if (e.name != "vertex") continue;
      for (const char* axis : {"x", "y", "z"})
        if (std::none_of(e.properties.begin(), e.properties.end(), [&](const Property& p) { return !p.list && p.name == axis; }))
          refuse(path_, "PLY vertex element without a scalar property '" + std::string(axis) + "'");
    }
    if (vertex_count_ > 3 * kMaxMeshTriangles) refuse(path_, std::to_string(vertex_count_) + " vertices, more than a panel mesh has");
    std::uint64_t faces = 0;
    for (const Element& e : elements_) faces += e.name == "face" ? e.count : 0;
    if (faces > kMaxMeshTriangles) refuse(path_, std::to_string(faces) + " faces, more than " + std::to_string(kMaxMeshTriangles));
    // The least each element can take (lists at their count alone): more than the file
    // holds is a cut file, said before anything is read.
    std::uint64_t least = 0;
    for (const Element& e : elements_) {
      std::uint64_t each = 0;
      for (const Property& p : e.properties) each += static_cast<std::uint64_t>(size_of(p.list ? p.count_type : p.type));
      least += format_ == Format::kAscii ? e.count * e.properties.size() * 2 : e.count * each;
    }
    if (least > bytes_.size() - pos_)
      refuse(path_, "the PLY body is cut short: its header needs at least " + std::to_string(least) + " bytes, the file has " +
                        std::to_string(bytes_.size() - pos_));
  }

  double scalar(const std::string& type) {
    if (format_ == Format::kAscii) {
      while (pos_ < bytes_.size() && std::isspace(static_cast<unsigned char>(bytes_[pos_])) != 0) ++pos_;
      const std::size_t start = pos_;
      while (pos_ < bytes_.size() && std::isspace(static_cast<unsigned char>(bytes_[pos_])) == 0) ++pos_;
      if (start == pos_) refuse(path_, "the PLY body ends before its header's counts");
      const std::string word = bytes_.substr(start, pos_ - start);
      char* end = nullptr;
      const double v = std::strtod(word.c_str(), &end);
      if (end != word.c_str() + word.size()) refuse(path_, "'" + word.substr(0, 40) + "' in the PLY body is not a number");
      return v;
    }
    unsigned char raw[8];
    // size_of() is 1 to 8 for every type the header accepted; the bound is said again
    // here for GCC 12, which at -O3 for aarch64 could not see it and warned of a write
    // past raw in std::reverse (-Wstringop-overflow, a plain Release build).
    const std::size_t n = std::min(static_cast<std::size_t>(size_of(type)), sizeof raw);
    if (bytes_.size() - pos_ < n) refuse(path_, "the PLY body ends before its header's counts");
    std::memcpy(raw, bytes_.data() + pos_, n);
    pos_ += n;
    if (format_ == Format::kBig) std::reverse(raw, raw + n);  // to little-endian, the hosts' order
    const auto get = [&](auto value) {
      std::memcpy(&value, raw, sizeof value);
      return static_cast<double>(value);
    };
    if (type == "char" || type == "int8") return get(std::int8_t{});
    if (type == "uchar" || type == "uint8") return get(std::uint8_t{});
    if (type == "short" || type == "int16") return get(std::int16_t{});
    if (type == "ushort" || type == "uint16") return get(std::uint16_t{});
    if (type == "int" || type == "int32") return get(std::int32_t{});
    if (type == "uint" || type == "uint32") return get(std::uint32_t{});
    if (type == "float" || type == "float32") return get(float{});
    return get(double{});
  }

  void skip_list(const Property& p) {
    const double n = scalar(p.count_type);
    if (!(n >= 0) || n > 1e6) refuse(path_, "a list of " + std::to_string(n) + " entries in the PLY body");
    for (std::size_t k = 0; k < static_cast<std::size_t>(n); ++k) scalar(p.type);
  }

  const std::string& path_;
  const std::string& bytes_;
  std::size_t pos_ = 0;
  int line_ = 0;
  Format format_ = Format::kAscii;
  std::vector<Element> elements_;
  std::uint64_t vertex_count_ = 0;
};

// Checks before assimp sees a file (it reads what it is given to the end): a binary STL's
// size is fixed by its triangle count, an ASCII STL ends with endsolid.
void check_stl(const std::string& path, const std::string& bytes) {
  const bool ascii = bytes.rfind("solid", 0) == 0 && bytes.find("facet", 0) != std::string::npos;
  if (ascii) {
    const std::size_t last = bytes.find_last_not_of(" \t\r\n");
    const std::size_t line = last == std::string::npos ? 0 : bytes.find_last_of('\n', last);
    const std::string tail = bytes.substr(line == std::string::npos ? 0 : line + 1);
    if (tail.find("endsolid") == std::string::npos) refuse(path, "an ASCII STL cut short: its last line is not endsolid");
    return;
  }
  if (bytes.size() < 84) refuse(path, "a binary STL of " + std::to_string(bytes.size()) + " bytes, shorter than its 84-byte header");
  std::uint32_t n = 0;
  std::memcpy(&n, bytes.data() + 80, 4);
  const std::uint64_t expected = 84 + 50ull * n;
  if (bytes.size() != expected)
    refuse(path, "a binary STL of " + std::to_string(n) + " triangles is " + std::to_string(expected) + " bytes, this one " +
                     std::to_string(bytes.size()));
}

}  // namespace

TriangleMesh parse_ply(const std::string& name, const std::string& bytes, double metres_per_unit) {
  TriangleMesh mesh = PlyReader(name, bytes).read(metres_per_unit);
  if (mesh.triangles.empty()) refuse(name, "no triangles in the mesh");
  return mesh;
}

TriangleMesh load_mesh(const std::string& path, double metres_per_unit) {
  if (!(metres_per_unit > 0) || !std::isfinite(metres_per_unit))
    throw std::runtime_error(path + ": metres per mesh unit must be a positive number, not " + std::to_string(metres_per_unit));
  const std::string bytes = read_bounded_file(path, kMaxMeshFileBytes, "a panel mesh");
  std::string ext = std::filesystem::path(path).extension().string();
  if (!ext.empty()) ext.erase(0, 1);
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  if (ext != "stl" && ext != "obj" && ext != "ply")
    throw std::runtime_error(path + ": a panel mesh must be .stl, .obj or .ply, not '" + ext + "'");
  if (ext == "ply") return parse_ply(path, bytes, metres_per_unit);
  if (ext == "stl") check_stl(path, bytes);
  Assimp::Importer importer;
  // No vertex joining or reordering: the file's vertices and triangles, in its order (an
  // STL's corners stay unshared; Embree does not mind).
  // Points and lines are not surface: dropped by the importer, not turned into triangles.
  importer.SetPropertyInteger(AI_CONFIG_PP_SBP_REMOVE, aiPrimitiveType_POINT | aiPrimitiveType_LINE);
  const aiScene* scene = importer.ReadFileFromMemory(
      bytes.data(), bytes.size(),
      aiProcess_Triangulate | aiProcess_PreTransformVertices | aiProcess_SortByPType,
      ext.c_str());
  if (scene == nullptr) throw std::runtime_error(path + ": not a readable mesh: " + importer.GetErrorString());
  TriangleMesh mesh;
  for (unsigned m = 0; m < scene->mNumMeshes; ++m) {
    const aiMesh& in = *scene->mMeshes[m];
    if ((in.mPrimitiveTypes & aiPrimitiveType_TRIANGLE) == 0) continue;
    const auto base = static_cast<std::uint32_t>(mesh.vertices.size());
    for (unsigned v = 0; v < in.mNumVertices; ++v) {
      const aiVector3D& p = in.mVertices[v];
      const Eigen::Vector3d q = Eigen::Vector3d(p.x, p.y, p.z) * metres_per_unit;
      if (!q.allFinite())
        throw std::runtime_error(path + ": mesh " + std::to_string(m) + " vertex " + std::to_string(v) + " is not a finite number");
      mesh.vertices.push_back(q);
    }
    for (unsigned f = 0; f < in.mNumFaces; ++f) {
      const aiFace& face = in.mFaces[f];
      if (face.mNumIndices != 3) continue;
      if (mesh.triangles.size() >= kMaxMeshTriangles)
        throw std::runtime_error(path + ": more than " + std::to_string(kMaxMeshTriangles) + " triangles");
      mesh.triangles.push_back({base + face.mIndices[0], base + face.mIndices[1], base + face.mIndices[2]});
    }
  }
  if (mesh.triangles.empty()) throw std::runtime_error(path + ": no triangles in the mesh");
  return mesh;
}

void save_mesh_ply(const std::string& path, const TriangleMesh& mesh) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out << "ply\nformat binary_little_endian 1.0\ncomment markcell panel mesh, panel frame, metres\n"
      << "element vertex " << mesh.vertices.size() << "\nproperty float x\nproperty float y\nproperty float z\n"
      << "element face " << mesh.triangles.size() << "\nproperty list uchar uint vertex_indices\nend_header\n";
  const auto put = [&](const auto& value) {
    // Little-endian on every architecture markcell builds for (amd64, arm64).
    char raw[sizeof value];
    std::memcpy(raw, &value, sizeof value);
    out.write(raw, sizeof value);
  };
  for (const auto& v : mesh.vertices)
    for (int i = 0; i < 3; ++i) put(static_cast<float>(v(i)));
  for (const auto& t : mesh.triangles) {
    put(static_cast<std::uint8_t>(3));
    for (const auto i : t) put(i);
  }
  out.flush();
  if (!out) throw std::runtime_error(path + ": cannot write the mesh");
}

struct MeshSurface::Embree {
  RTCDevice device = nullptr;
  RTCScene scene = nullptr;
  ~Embree() {
    if (scene != nullptr) rtcReleaseScene(scene);
    if (device != nullptr) rtcReleaseDevice(device);
  }
};

namespace {
[[noreturn]] void embree_failed(RTCDevice device, const char* what) {
  throw std::runtime_error(std::string("Embree: ") + what + " failed (error " + std::to_string(rtcGetDeviceError(device)) + ")");
}
}  // namespace

MeshSurface::MeshSurface(TriangleMesh mesh) : mesh_(std::move(mesh)), embree_(std::make_unique<Embree>()) {
  if (mesh_.triangles.empty()) throw std::invalid_argument("a panel mesh needs at least one triangle");
  for (const auto& t : mesh_.triangles)
    for (const auto i : t)
      if (i >= mesh_.vertices.size())
        throw std::invalid_argument("triangle vertex index " + std::to_string(i) + " beyond the mesh's " +
                                    std::to_string(mesh_.vertices.size()) + " vertices");
  for (const auto& v : mesh_.vertices) bounds_.extend(v);
  // One build thread: the BVH is the same on every run, and a panel builds in milliseconds.
  embree_->device = rtcNewDevice("threads=1");
  if (embree_->device == nullptr) throw std::runtime_error("Embree: cannot create a device");
  embree_->scene = rtcNewScene(embree_->device);
  if (embree_->scene == nullptr) embree_failed(embree_->device, "rtcNewScene");
  rtcSetSceneFlags(embree_->scene, RTC_SCENE_FLAG_ROBUST);
  rtcSetSceneBuildQuality(embree_->scene, RTC_BUILD_QUALITY_HIGH);
  RTCGeometry geometry = rtcNewGeometry(embree_->device, RTC_GEOMETRY_TYPE_TRIANGLE);
  if (geometry == nullptr) embree_failed(embree_->device, "rtcNewGeometry");
  // (rtcSetNewGeometryBuffer pads the vertex buffer for Embree's 16-byte loads itself.)
  auto* vertices = static_cast<float*>(
      rtcSetNewGeometryBuffer(geometry, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, 3 * sizeof(float), mesh_.vertices.size()));
  auto* indices = static_cast<unsigned*>(
      rtcSetNewGeometryBuffer(geometry, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, 3 * sizeof(unsigned), mesh_.triangles.size()));
  if (vertices == nullptr || indices == nullptr) {
    rtcReleaseGeometry(geometry);
    embree_failed(embree_->device, "rtcSetNewGeometryBuffer");
  }
  for (std::size_t i = 0; i < mesh_.vertices.size(); ++i)
    for (int k = 0; k < 3; ++k) vertices[3 * i + static_cast<std::size_t>(k)] = static_cast<float>(mesh_.vertices[i](k));
  for (std::size_t i = 0; i < mesh_.triangles.size(); ++i)
    for (std::size_t k = 0; k < 3; ++k) indices[3 * i + k] = mesh_.triangles[i][k];
  rtcCommitGeometry(geometry);
  rtcAttachGeometry(embree_->scene, geometry);
  rtcReleaseGeometry(geometry);
  rtcCommitScene(embree_->scene);
  if (rtcGetDeviceError(embree_->device) != RTC_ERROR_NONE) embree_failed(embree_->device, "building the panel's BVH");
}

MeshSurface::~MeshSurface() = default;

namespace {
void init_ray(RTCRayHit& rh, const Eigen::Vector3d& o, const Eigen::Vector3d& d_unit) {
  rh.ray.org_x = static_cast<float>(o.x());
  rh.ray.org_y = static_cast<float>(o.y());
  rh.ray.org_z = static_cast<float>(o.z());
  rh.ray.dir_x = static_cast<float>(d_unit.x());
  rh.ray.dir_y = static_cast<float>(d_unit.y());
  rh.ray.dir_z = static_cast<float>(d_unit.z());
  rh.ray.tnear = 0.0f;
  rh.ray.tfar = std::numeric_limits<float>::infinity();
  rh.ray.mask = 0xFFFFFFFFu;
  rh.ray.flags = 0;
  rh.ray.time = 0.0f;
  rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
  rh.hit.primID = RTC_INVALID_GEOMETRY_ID;
}
}  // namespace

// The triangle Embree found, met again in double precision (Moeller-Trumbore's plane
// distance; the barycentric bounds are Embree's call, made once).
MeshHit MeshSurface::refine(std::uint32_t triangle, const Eigen::Vector3d& o, const Eigen::Vector3d& d) const {
  MeshHit out;
  if (triangle >= mesh_.triangles.size()) return out;
  const auto& tri = mesh_.triangles[triangle];
  const Eigen::Vector3d& a = mesh_.vertices[tri[0]];
  const Eigen::Vector3d e1 = mesh_.vertices[tri[1]] - a, e2 = mesh_.vertices[tri[2]] - a;
  Eigen::Vector3d n = e1.cross(e2);
  const double nn = n.norm();
  const double denom = n.dot(d);
  if (!(nn > 0) || denom == 0.0) return out;
  const double t = n.dot(a - o) / denom;
  if (!(t > 0)) return out;
  n /= nn;
  out.t = t;
  out.p = o + t * d;
  out.normal = n.dot(d) > 0 ? Eigen::Vector3d(-n) : n;
  out.triangle = triangle;
  return out;
}

MeshHit MeshSurface::intersect(const Eigen::Vector3d& o, const Eigen::Vector3d& d) const {
  const double scale = d.norm();
  if (!(scale > 0) || !o.allFinite() || !d.allFinite()) return MeshHit{};
  RTCIntersectContext context;
  rtcInitIntersectContext(&context);
  RTCRayHit rh{};
  init_ray(rh, o, d / scale);
  rtcIntersect1(embree_->scene, &context, &rh);
  if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) return MeshHit{};
  return refine(rh.hit.primID, o, d);
}

void MeshSurface::intersect(const Eigen::Vector3d& o, const Eigen::Vector3d* d, std::size_t n, MeshHit* out) const {
  // In chunks, as a stream of coherent rays (a camera's neighbouring pixels): Embree
  // traces them as packets, several times faster than one by one, same answers.
  constexpr std::size_t kChunk = 64;
  std::array<RTCRayHit, kChunk> rays;
  std::array<bool, kChunk> valid{};
  RTCIntersectContext context;
  for (std::size_t first = 0; first < n; first += kChunk) {
    const std::size_t m = std::min(kChunk, n - first);
    for (std::size_t i = 0; i < m; ++i) {
      const Eigen::Vector3d& di = d[first + i];
      const double scale = di.norm();
      valid[i] = scale > 0 && o.allFinite() && di.allFinite();
      init_ray(rays[i], o, valid[i] ? Eigen::Vector3d(di / scale) : Eigen::Vector3d::UnitZ());
      if (!valid[i]) rays[i].ray.tfar = -1.0f;  // Embree skips a ray with tfar < tnear
    }
    rtcInitIntersectContext(&context);
    context.flags = RTC_INTERSECT_CONTEXT_FLAG_COHERENT;
    rtcIntersect1M(embree_->scene, &context, rays.data(), static_cast<unsigned>(m), sizeof(RTCRayHit));
    for (std::size_t i = 0; i < m; ++i)
      out[first + i] = valid[i] && rays[i].hit.geomID != RTC_INVALID_GEOMETRY_ID ? refine(rays[i].hit.primID, o, d[first + i]) : MeshHit{};
  }
}

MeshHit MeshSurface::from_front(double x, double y) const {
  const double above = bounds_.max().z() + 1.0;
  return intersect(Eigen::Vector3d(x, y, above), Eigen::Vector3d(0, 0, -1));
}

}  // namespace markcell::rig
