// The volume reader for NIfTI through nifti_clib
#include "volume/volume_io.h"

#include <nifti2_io.h>
#include <zlib.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <map>
#include <memory>
#include <optional>
#include <filesystem>
#include <iomanip>
#include <sstream>

#include "volume/core/file_util.h"
#include "volume/core/memory_limit.h"
#include "volume/inflate.h"
#include "volume/patient_frame.h"
#include "volume/plane_source.h"
#include "volume/plane_stack.h"
#include "volume/reader_util.h"
#include "volume/text_reader.h"

namespace hyb {

namespace fs = std::filesystem;
using namespace detail;  // the readers' shared helpers

namespace {

// A sform whose first two columns are orthogonal but whose third leaves their normal (dcm2niix's
// conversion of a gantry-tilted series): the stack of its planes, each at origin + k·column 3.
std::optional<PlaneStack> shearedStack(const glm::dmat3& d, const glm::dvec3& origin, const glm::ivec3& dims, const std::string& path) {
  for (int c = 0; c < 3; ++c)  // a non-finite sform is refused by the frame's own check, rethrown
    if (!std::isfinite(glm::dot(d[c], glm::dvec3(1.0))) || !std::isfinite(origin[c])) return std::nullopt;
  const double l0 = glm::length(d[0]), l1 = glm::length(d[1]);
  if (!(l0 > 0.0 && l1 > 0.0) || std::abs(glm::dot(d[0], d[1])) > 1e-3 * l0 * l1) return std::nullopt;
  glm::dvec3 n = glm::cross(d[0] / l0, d[1] / l1);
  if (glm::dot(n, d[2]) < 0.0) n = -n;  // the planes in the file's order are in increasing depth
  if (glm::dot(glm::normalize(d[2]), n) < 0.1) return std::nullopt;  // the third axis nearly in the plane: not a stack
  PlaneStack s;
  s.axes = makePatientFrame(glm::dmat3(d[0] / l0, d[1] / l1, n), glm::dvec3(0.0), path + " (sform)").direction;
  s.pixelSpacing = {l0, l1};
  s.size = {dims.x, dims.y};
  for (int k = 0; k < dims.z; ++k) {
    s.origins.push_back(origin + double(k) * d[2]);
    s.names.push_back(concat(path, " (plane ", k, ")"));
  }
  return s;
}

// The patient frame of a NIfTI image, with the precedence of ITK (5.x) and nibabel: the sform when
// its code is set, else the qform (nifti_clib's qto_xyz: quaternion, qfac and pixdim), else NIfTI's
// method 1 (RAS axes, origin 0) with a warning. NIfTI's world is RAS; the frame is LPS. A sform
// sheared along its third axis (a tilted acquisition) is honoured: @p grid receives the orthogonal
// grid its planes are resampled onto (ITK would take the qform instead, drawing the planes where
// the file says they are not).
PatientFrame niftiFrame(const nifti_image& nim, const std::string& path, const glm::ivec3& dims, glm::dvec3* spacing,
                        std::vector<std::string>* warnings, std::optional<StackGrid>* grid) {
  const double unit = nim.xyz_units == NIFTI_UNITS_METER ? 1000.0 : nim.xyz_units == NIFTI_UNITS_MICRON ? 1e-3 : 1.0;
  auto columns = [&](const nifti_dmat44& m, glm::dvec3* origin) {
    glm::dmat3 d;
    for (int c = 0; c < 3; ++c) d[c] = rasToLps(glm::dvec3(m.m[0][c], m.m[1][c], m.m[2][c]) * unit);
    *origin = rasToLps(glm::dvec3(m.m[0][3], m.m[1][3], m.m[2][3]) * unit);
    return d;
  };
  auto fromMatrix = [&](const nifti_dmat44& m, const char* name) {
    glm::dvec3 origin;
    const glm::dmat3 d = columns(m, &origin);
    for (int c = 0; c < 3; ++c) (*spacing)[c] = glm::length(d[c]);
    return makePatientFrame(d, origin, path + " (" + name + ")");
  };
  if (nim.sform_code > 0) {
    try {
      return fromMatrix(nim.sto_xyz, "sform");
    } catch (const ValueError&) {
      glm::dvec3 origin;
      const glm::dmat3 d = columns(nim.sto_xyz, &origin);
      const std::optional<PlaneStack> stack = shearedStack(d, origin, dims, path);
      if (!stack) throw;
      *grid = stackGrid(*stack, path, "a sheared sform");
      *spacing = (*grid)->resampled ? glm::dvec3(stack->pixelSpacing, 1.0) : (*grid)->spacing;  // (resampled: the grid's replaces it)
      PatientFrame f;
      f.direction = stack->axes;
      f.origin = origin;
      return f;
    }
  }
  if (nim.qform_code > 0) return fromMatrix(nim.qto_xyz, "qform");
  warnings->push_back(path + ": qform_code and sform_code are 0 (no orientation): read as NIfTI's method 1 does, RAS axes with the origin at 0");
  *spacing *= unit;
  PatientFrame frame = makePatientFrame(glm::dmat3(glm::dvec3(-1, 0, 0), glm::dvec3(0, -1, 0), glm::dvec3(0, 0, 1)), glm::dvec3(0.0), path);
  frame.assumed = true;
  return frame;
}

}  // namespace

namespace {

// Checks the data file nifti_clib will read against the header's claim before it allocates:
// a plain file must hold the bytes, a gzip one must be able to inflate to them.
void checkNiftiData(const nifti_image& nim, const std::string& path) {
  if (!nim.iname) HYB_THROW(IoError, path, ": NIfTI header names no data file");
  const InputFile data(nim.iname);
  const uint64_t offset = uint64_t(std::max<int64_t>(0, nim.iname_offset));
  const uint64_t bytes = uint64_t(nim.nvox) * uint64_t(nim.nbyper);
  const uint64_t needed = offset + bytes;
  const bool gz = fileExtension(nim.iname).ends_with(".gz");
  if (!gz && data.size() < needed)
    HYB_THROW(IoError, data.path(), ": truncated NIfTI data: expected ", bytes, " bytes of samples from byte ", offset, ", found ",
              data.size() > offset ? data.size() - offset : 0);
  if (gz && detail::maxInflatedBytes(data.size()) < needed)
    HYB_THROW(IoError, data.path(), ": ", data.size(), " bytes of compressed data cannot hold the ", needed,
              " bytes the header declares (expected more: deflate inflates at most ", detail::kMaxDeflateRatio, ":1)");
}

using NiftiImage = std::unique_ptr<nifti_image, void (*)(nifti_image*)>;
constexpr int kMsbFirst = 2;  // nifti_image::byteorder of a big-endian file (MSB_FIRST, which nifti_clib keeps to itself)

// A NIfTI file's header, checked, with the volume it describes (no samples) and where its samples lie.
struct NiftiLayout {
  NiftiImage nim{nullptr, nifti_image_free};
  Volume description;
  SampleData data;
  double slope = 1.0, inter = 0.0;  // scl_slope and scl_inter where they rescale the samples
  bool rescaled() const { return slope != 1.0 || inter != 0.0; }
  std::optional<StackGrid> grid;  // a sheared sform's: its planes resampled onto it
};

NiftiLayout parseNifti(const std::string& path) {
  const InputFile header(path);  // refuses FIFOs and directories before nifti_clib opens them
  nifti_set_debug_level(0);  // we report errors ourselves, in one line
  // The header first: the data is loaded only once its size is proven by the file. nifti_clib
  // prints some errors whatever its debug level; they are captured and quoted in ours.
  detail::StderrCapture capture;
  NiftiLayout l;
  l.nim.reset(nifti_image_read(path.c_str(), 0));
  const std::string said = capture.finish();
  const nifti_image* nim = l.nim.get();
  if (!nim)
    HYB_THROW(IoError, path, ": not a readable NIfTI-1/2 image", said.empty() ? "" : " (nifti_clib: " + quotedExcerpt(said, 120) + ")",
              " (expected a NIfTI-1 or NIfTI-2 header)");
  for (int d = 4; d <= nim->ndim && d < 8; ++d)
    if (nim->dim[d] > 1)
      HYB_THROW(IoError, path, ": NIfTI image has ", nim->ndim, " dimensions with extent ", nim->dim[d],
                " along axis ", d, " (expected one 3D volume)");
  if (nim->nx < 1 || nim->nx > kMaxDim || nim->ny > kMaxDim || nim->nz > kMaxDim || nim->nvox < 1 || nim->nbyper < 1 || nim->nbyper > 32)
    HYB_THROW(IoError, path, ": NIfTI dims ", nim->nx, "x", nim->ny, "x", nim->nz, " invalid (expected 1..", kMaxDim, " per axis)");
  checkNiftiData(*nim, path);
  const glm::ivec3 dims(int(nim->nx), int(std::max<int64_t>(1, nim->ny)), int(std::max<int64_t>(1, nim->nz)));
  validateDims(dims, path);
  ScalarType type;
  switch (nim->datatype) {
    case DT_UINT8: type = ScalarType::UInt8; break;
    case DT_INT8: type = ScalarType::Int8; break;
    case DT_UINT16: type = ScalarType::UInt16; break;
    case DT_INT16: type = ScalarType::Int16; break;
    case DT_UINT32: type = ScalarType::UInt32; break;
    case DT_INT32: type = ScalarType::Int32; break;
    case DT_FLOAT32: type = ScalarType::Float32; break;
    case DT_FLOAT64: type = ScalarType::Float64; break;
    default:
      HYB_THROW(IoError, path, ": NIfTI datatype ", nim->datatype, " unsupported (expected a real scalar type)");
  }
  glm::dvec3 spacing(std::fabs(nim->dx), std::fabs(nim->dy > 0 ? nim->dy : 1.0), std::fabs(nim->dz > 0 ? nim->dz : 1.0));
  std::vector<std::string> warnings;
  const PatientFrame frame = niftiFrame(*nim, path, dims, &spacing, &warnings, &l.grid);
  validateSpacing(spacing, path);
  l.description = placed(describedVolume(dims, spacing, type, path), frame, warnings);
  // A .nii.gz is one gzip stream, the header inside it: the samples start vox_offset inflated bytes in.
  const uint64_t offset = uint64_t(std::max<int64_t>(0, nim->iname_offset));
  const bool gz = fileExtension(nim->iname).ends_with(".gz");
  l.data = SampleData{nim->iname, gz ? 0 : offset, gz ? (long long)offset : 0, "vox_offset", gz, type, nim->byteorder == kMsbFirst};
  if (std::isfinite(nim->scl_slope) && nim->scl_slope != 0.0 && std::isfinite(nim->scl_inter)) {
    l.slope = nim->scl_slope;
    l.inter = nim->scl_inter;
  }
  return l;
}

}  // namespace

Volume readNifti(const std::string& path) {
  NiftiLayout l = parseNifti(path);
  nifti_image* nim = l.nim.get();
  checkMemory(path, uint64_t(nim->nvox) * uint64_t(nim->nbyper) + uint64_t(nim->nvox) * sizeof(float), detail::concat(nim->nvox, " NIfTI samples"));
  detail::StderrCapture loadCapture;
  const bool loaded = nifti_image_load(nim) == 0 && nim->data;
  const std::string loadSaid = loadCapture.finish();
  if (!loaded)
    HYB_THROW(IoError, path, ": NIfTI data could not be read", loadSaid.empty() ? "" : " (nifti_clib: " + quotedExcerpt(loadSaid, 120) + ")",
              " (expected ", uint64_t(nim->nvox) * uint64_t(nim->nbyper), " bytes of samples)");
  const glm::ivec3 dims = l.description.dims();
  ScalarType type = l.description.sourceType();
  const size_t count = size_t(dims.x) * dims.y * dims.z;
  // nifti_clib has already swapped to native byte order.
  SampleArray samples = decodeSamples(static_cast<const uint8_t*>(nim->data), count, type, std::endian::native == std::endian::big);
  if (l.rescaled()) {
    SampleArray values = detail::rescaleTarget(type, l.slope, l.inter, count);
    detail::rescaleSamples(&values, 0, samples, l.slope, l.inter);
    samples = std::move(values);
    if (storedType(samples) == ScalarType::Float32) type = ScalarType::Float32;
  }
  Volume v = placedAs(Volume(dims, l.description.spacing(), type, std::move(samples), path), l.description);
  if (!l.grid || !l.grid->resampled) return v;
  return readAllPlanes(*resampledPlanes(planesOwning(std::make_shared<const Volume>(std::move(v)), path), *l.grid));
}

std::unique_ptr<PlaneSource> detail::niftiPlanes(const std::string& path) {
  NiftiLayout l = parseNifti(path);
  if (!streams(l.data.type) || l.rescaled()) return nullptr;  // a rescale may change the stored type: read whole
  std::optional<StackGrid> grid = std::move(l.grid);
  std::unique_ptr<PlaneSource> planes = streamedPlanes(l.data, std::move(l.description), path);
  return grid ? resampledPlanes(std::move(planes), std::move(*grid)) : std::move(planes);
}

namespace {

// The NIfTI-1 datatype of a stored sample type (every SampleArray type has one).
short niftiDatatype(ScalarType t) {
  switch (t) {
    case ScalarType::UInt8: return DT_UINT8;
    case ScalarType::Int8: return DT_INT8;
    case ScalarType::UInt16: return DT_UINT16;
    case ScalarType::Int16: return DT_INT16;
    default: return DT_FLOAT32;
  }
}

// The NIfTI-1 header of @p volume: its grid in RAS (x and y of the LPS frame negated) as both the
// sform and the qform, so that readers taking either (this one and nibabel the sform, others the
// qform) place it alike.
nifti_1_header niftiHeader(const Volume& volume, const std::string& path) {
  static_assert(sizeof(nifti_1_header) == 348);
  const glm::ivec3 dims = volume.dims();
  constexpr int kNiftiMaxDim = 32767;  // dim[] is a short
  if (dims.x > kNiftiMaxDim || dims.y > kNiftiMaxDim || dims.z > kNiftiMaxDim)
    HYB_THROW(IoError, path, ": ", dims.x, "x", dims.y, "x", dims.z, " voxels do not fit NIfTI-1 (expected at most ", kNiftiMaxDim, " per axis)");
  nifti_1_header h;
  std::memset(&h, 0, sizeof h);
  h.sizeof_hdr = 348;
  h.dim[0] = 3;
  for (int a = 0; a < 3; ++a) h.dim[a + 1] = short(dims[a]);
  for (int a = 4; a < 8; ++a) h.dim[a] = 1;
  h.datatype = niftiDatatype(volume.storedType());
  h.bitpix = short(8 * scalarSize(volume.storedType()));
  h.vox_offset = 352.0f;  // the header and the 4 bytes saying no extension follows
  h.scl_slope = 1.0f;
  h.xyzt_units = NIFTI_UNITS_MM;
  std::strncpy(h.descrip, "hybrid-octree", sizeof h.descrip);
  std::memcpy(h.magic, "n+1", 4);
  // The affine: column a is axis a's RAS direction times its spacing; column 3 the origin (RAS;
  // rasToLps is its own inverse).
  nifti_dmat44 m{};
  const PatientFrame& f = volume.frame();
  for (int a = 0; a < 3; ++a) {
    const glm::dvec3 c = rasToLps(f.direction[a] * volume.spacing()[a]);
    for (int r = 0; r < 3; ++r) m.m[r][a] = c[r];
  }
  const glm::dvec3 o = rasToLps(f.origin);
  for (int r = 0; r < 3; ++r) m.m[r][3] = o[r];
  m.m[3][3] = 1.0;
  float* rows[3] = {h.srow_x, h.srow_y, h.srow_z};
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 4; ++c) rows[r][c] = float(m.m[r][c]);
  double qb, qc, qd, qx, qy, qz, dx, dy, dz, qfac;
  nifti_dmat44_to_quatern(m, &qb, &qc, &qd, &qx, &qy, &qz, &dx, &dy, &dz, &qfac);
  h.quatern_b = float(qb);
  h.quatern_c = float(qc);
  h.quatern_d = float(qd);
  h.qoffset_x = float(qx);
  h.qoffset_y = float(qy);
  h.qoffset_z = float(qz);
  h.pixdim[0] = float(qfac);
  for (int a = 0; a < 3; ++a) h.pixdim[a + 1] = float(volume.spacing()[a]);
  // A frame the CT's reader assumed is only aligned to that file as read here, not the scanner's.
  h.qform_code = h.sform_code = short(f.assumed ? NIFTI_XFORM_ALIGNED_ANAT : NIFTI_XFORM_SCANNER_ANAT);
  return h;
}

// Writes @p size bytes to @p out, deflated through the gzip stream @p z when it is not null;
// @p flush Z_FINISH ends that stream.
void writeBytes(std::ostream& out, z_stream* z, const void* data, size_t size, const std::string& path, int flush = Z_NO_FLUSH) {
  if (!z) {
    out.write(static_cast<const char*>(data), std::streamsize(size));
    return;
  }
  unsigned char chunk[1 << 16];
  z->next_in = static_cast<Bytef*>(const_cast<void*>(data));
  do {
    const uInt in = uInt(std::min<size_t>(size, 1u << 30));  // avail_in is 32 bits
    z->avail_in = in;
    size -= in;
    do {
      z->next_out = chunk;
      z->avail_out = sizeof chunk;
      if (deflate(z, size == 0 ? flush : Z_NO_FLUSH) == Z_STREAM_ERROR) HYB_THROW(IoError, path, ": gzip compression failed");
      out.write(reinterpret_cast<const char*>(chunk), std::streamsize(sizeof chunk - z->avail_out));
    } while (z->avail_out == 0);
  } while (size > 0);
}

}  // namespace

void writeNifti(const Volume& volume, const std::string& path) {
  const nifti_1_header header = niftiHeader(volume, path);
  const bool gz = fileExtension(path).ends_with(".gz");
  writeFileAtomically(path, [&](std::ostream& out) {
    z_stream z{};
    if (gz && deflateInit2(&z, Z_DEFAULT_COMPRESSION, Z_DEFLATED, 15 + 16, 8, Z_DEFAULT_STRATEGY) != Z_OK)  // 15 + 16: a gzip wrapper
      HYB_THROW(IoError, path, ": gzip compression could not start");
    std::unique_ptr<z_stream, int (*)(z_stream*)> end(gz ? &z : nullptr, deflateEnd);
    const uint32_t noExtension = 0;
    writeBytes(out, end.get(), &header, sizeof header, path);
    writeBytes(out, end.get(), &noExtension, sizeof noExtension, path);
    volume.visitSamples([&](const auto* samples) { writeBytes(out, end.get(), samples, volume.voxelCount() * sizeof(*samples), path); });
    if (gz) writeBytes(out, &z, nullptr, 0, path, Z_FINISH);
  });
}

}  // namespace hyb
