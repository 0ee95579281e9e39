// The Python module `hybrid_octree` (pybind11): numpy volumes in without copying their samples,
// images and meshes out, through the engine the command line uses. Rendering options are the
// command line's flags as keyword arguments, parsed and checked by the same code, so a mistake gets
// the command line's message. README "Python"; the API with types: apps/python/hybrid_octree.pyi.
#include <nlohmann/json.hpp>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <Python.h>

#include <algorithm>
#include <cmath>
#include <atomic>
#include <mutex>
#include <thread>
#include <sstream>

#include "hybrid_octree/hybrid_io.h"
#include "hybrid_octree/surface_export.h"
#include "render/frame_settings.h"
#include "render/orientation_marker.h"
#include "render/scene_renderer.h"
#include "surface/mesh_io.h"
#include "volume/core/error.h"
#include "volume/core/file_util.h"
#include "volume/core/number_text.h"
#include "volume/reader_util.h"

namespace py = pybind11;

namespace hyb::app {
namespace {

// Thrown by the progress callback when Python has a KeyboardInterrupt (or another signal's
// exception) pending: it stops the frame, and the pending exception is raised.
struct Interrupted : std::runtime_error {
  Interrupted() : std::runtime_error("interrupted") {}
};

// Keeps a numpy array alive for the samples a Volume borrows; released with the GIL held.
struct ArrayKeeper {
  py::object array;
  ~ArrayKeeper() {
    if (!Py_IsInitialized()) {
      array.release();  // the interpreter is gone: nothing to give back
      return;
    }
    py::gil_scoped_acquire gil;
    array = py::object();
  }
};

ScalarType scalarOf(const py::dtype& dt) {
  if (dt.byteorder() == '>') throw py::type_error(hyb::detail::concat("dtype ", std::string(py::str(py::handle(dt))), " is big-endian (expected the machine's byte order: array.astype(array.dtype.newbyteorder('=')))"));
  const char kind = dt.kind();
  const size_t size = size_t(dt.itemsize());
  if (kind == 'u' && size == 1) return ScalarType::UInt8;
  if (kind == 'i' && size == 1) return ScalarType::Int8;
  if (kind == 'u' && size == 2) return ScalarType::UInt16;
  if (kind == 'i' && size == 2) return ScalarType::Int16;
  if (kind == 'u' && size == 4) return ScalarType::UInt32;
  if (kind == 'i' && size == 4) return ScalarType::Int32;
  if (kind == 'f' && size == 4) return ScalarType::Float32;
  if (kind == 'f' && size == 8) return ScalarType::Float64;
  throw py::type_error(hyb::detail::concat("dtype ", std::string(py::str(py::handle(dt))), " unsupported (expected uint8, int8, uint16, int16, uint32, int32, float32 or float64)"));
}

// How a keyword is written in Python; the flag's own text (a str) is accepted by every form but Flag.
enum class Form {
  Number,   // a real number: int, float, a numpy scalar or 0-d array
  Integer,  // an integer: int, a numpy integer or 0-d integer array
  Numbers,  // a 1-D sequence of numbers (tuple, list, numpy array): "a,b,c"
  Size,     // two integers (width, height): "WxH"
  Word,     // text only: a choice, or a path (str or os.PathLike)
  Switch,   // True/False: on|off
  Flag,     // True/False: the flag given or not
};

const char* expectedFor(Form form) {
  switch (form) {
    case Form::Number: return "a number (or its text)";
    case Form::Integer: return "an integer (or its text)";
    case Form::Numbers: return "a sequence of numbers (tuple, list or 1-D array; or their text 'a,b,...')";
    case Form::Size: return "(width, height) integers (or 'WxH')";
    case Form::Word: return "a str";
    case Form::Switch: return "True, False, 'on' or 'off'";
    case Form::Flag: break;
  }
  return "True or False";
}

// @p v is no value of @p form (an element of sequence @p within, when given).
[[noreturn]] void wrongType(const std::string& key, Form form, const py::handle& v, const py::handle& within = py::handle()) {
  throw py::type_error(hyb::detail::concat(key, " must be ", expectedFor(form), ", got ", Py_TYPE(v.ptr())->tp_name,
                                           within ? std::string(" in a ") + Py_TYPE(within.ptr())->tp_name : ""));
}

// A numpy 0-d array as its scalar; anything else as it is.
py::object itemOf(const py::handle& v) {
  if (py::isinstance<py::array>(v) && py::reinterpret_borrow<py::array>(v).ndim() == 0) return v.attr("item")();
  return py::reinterpret_borrow<py::object>(v);
}

bool isBool(const py::handle& v) { return PyBool_Check(v.ptr()) || py::isinstance(v, py::module_::import("numpy").attr("bool_")); }

// @p v's text when it is a number (an integer when @p integer): ints as digits, floats as Python's
// repr (the shortest text that reads back as the same double). None for bools and anything else.
std::optional<std::string> numberText(const py::handle& h, bool integer) {
  const py::object v = itemOf(h);
  if (isBool(v)) return std::nullopt;
  const py::module_ numbers = py::module_::import("numbers");
  if (py::isinstance(v, numbers.attr("Integral"))) return std::string(py::str(py::int_(v)));
  if (!integer && py::isinstance(v, numbers.attr("Real"))) return std::string(py::repr(py::float_(v)));
  return std::nullopt;
}

// A path given as str or os.PathLike, else nothing.
std::optional<std::string> pathText(const py::handle& v) {
  if (py::isinstance<py::str>(v)) return py::cast<std::string>(v);
  if (py::hasattr(v, "__fspath__")) {
    const py::object p = py::module_::import("os").attr("fspath")(v);
    if (py::isinstance<py::str>(p)) return py::cast<std::string>(p);
  }
  return std::nullopt;
}

// The text of keyword @p key's value @p v written in @p form (not Flag): what its flag reads. A value
// that no text of the form spells raises TypeError; the flag's parser refuses a wrong value.
std::string spelled(const std::string& key, const py::handle& h, Form form) {
  const py::object v = itemOf(h);
  if (py::isinstance<py::str>(v)) return py::cast<std::string>(v);
  switch (form) {
    case Form::Number:
    case Form::Integer:
      if (auto t = numberText(v, form == Form::Integer)) return *t;
      break;
    case Form::Numbers:
    case Form::Size: {
      const bool array = py::isinstance<py::array>(v);
      if ((array && py::reinterpret_borrow<py::array>(v).ndim() != 1) || (!array && !py::isinstance<py::list>(v) && !py::isinstance<py::tuple>(v))) break;
      std::string out;
      for (const py::handle x : v) {
        const std::optional<std::string> t = numberText(x, form == Form::Size);
        if (!t) wrongType(key, form, x, v);
        out += (out.empty() ? "" : form == Form::Size ? "x" : ",") + *t;
      }
      return out;
    }
    case Form::Word:
      if (auto t = pathText(v)) return *t;
      break;
    case Form::Switch:
      if (isBool(v)) return py::cast<bool>(py::bool_(v)) ? "on" : "off";
      break;
    case Form::Flag: break;
  }
  wrongType(key, form, v);
}

// The Python forms of a field: what its kind's text is spelled from.
Form formOf(const FrameField& f) {
  switch (f.kind) {
    case FieldKind::Number: return Form::Number;
    case FieldKind::Integer: return Form::Integer;
    case FieldKind::Budget: return Form::Number;  // megabytes, or a str "P%"
    case FieldKind::Numbers: return Form::Numbers;
    case FieldKind::Size: return Form::Size;
    case FieldKind::Switch: return Form::Switch;
    case FieldKind::Flag: return Form::Flag;
    case FieldKind::Choice:  // choices that are numbers (texel_bits 8 or 16) are written as numbers
      return std::all_of(f.choices.begin(), f.choices.end(), [](const std::string& c) { return c.find_first_not_of("0123456789") == std::string::npos; })
                 ? Form::Integer
                 : Form::Word;
    case FieldKind::Text:
    case FieldKind::Points: return Form::Word;
  }
  return Form::Word;
}

// A True/False keyword (numpy's bool too).
bool flagOf(const std::string& key, const py::handle& h) {
  const py::object v = itemOf(h);
  if (!isBool(v)) wrongType(key, Form::Flag, v);
  return py::cast<bool>(py::bool_(v));
}

// One finite number written in @p form (an isovalue, a count), its wrong text refused naming @p key.
double numberOf(const std::string& key, const py::handle& v, Form form = Form::Number) {
  const std::string text = spelled(key, v, form);
  const double x = parseNumbers(text, key, 1, form == Form::Integer ? "an integer" : "a finite number")[0];
  if (form == Form::Integer && x != std::floor(x)) HYB_THROW(ValueError, key, " '", text, "' invalid (expected an integer)");
  return x;
}

// The samples' range and whether every one is a whole number: what their stored type is chosen from.
struct ValueScan {
  double lo = 0, hi = 0;
  bool whole = true;
};

// Scans the @p count samples at @p d (x fastest within @p dims); a value float32 cannot hold (NaN,
// infinity, beyond 3.4e38) is refused naming its sample, as a reader refuses one.
template <class T>
ValueScan scanValues(const T* d, size_t count, const glm::ivec3& dims) {
  constexpr double kFloatMax = std::numeric_limits<float>::max();
  double lo = std::numeric_limits<double>::infinity(), hi = -lo;
  bool whole = true, held = true;
#pragma omp parallel for reduction(min : lo) reduction(max : hi) reduction(&& : whole) reduction(&& : held)
  for (size_t i = 0; i < count; ++i) {
    const double v = double(d[i]);
    held = held && std::abs(v) <= kFloatMax;  // false for NaN too
    whole = whole && v == std::trunc(v);
    lo = std::min(lo, v);
    hi = std::max(hi, v);
  }
  if (!held) {
    size_t bad = 0;
    while (std::abs(double(d[bad])) <= kFloatMax) ++bad;
    const size_t i = bad % size_t(dims.x), j = (bad / size_t(dims.x)) % size_t(dims.y), k = bad / (size_t(dims.x) * size_t(dims.y));
    HYB_THROW(ValueError, "numpy array: sample (", i, ",", j, ",", k, ") is ", double(d[bad]), "; expected finite values within float32's range (|x| <= 3.4e38)");
  }
  return {lo, hi, whole};
}

// Where converted samples are held: whole numbers in the smallest of uint8, int16 and uint16 that
// holds them all (beyond 16 bits, float32, as the readers hold 32-bit integers); fractions in float32.
ScalarType storedTypeOf(const ValueScan& s) {
  if (!s.whole) return ScalarType::Float32;
  if (s.lo >= 0 && s.hi <= 255) return ScalarType::UInt8;
  return storageTypeFor(ScalarType::Int32, s.lo, s.hi);
}

// A volume over @p array's samples: borrowed when held in their own type (uint8, int8, uint16,
// int16, float32), else converted into storedTypeOf their values: one pass reads their range, a
// second writes the stored copy, and nothing else of the array's size is held.
Volume volumeOf(const py::handle& object, const glm::dvec3& spacing) {
  if (!py::isinstance<py::array>(object))
    throw py::type_error(hyb::detail::concat("array must be a numpy array (numpy.asarray makes one), got ", Py_TYPE(object.ptr())->tp_name));
  const py::array array = py::reinterpret_borrow<py::array>(object);
  if (array.ndim() != 3)
    HYB_THROW(ValueError, "expected a 3-D array indexed (z, y, x), got ", array.ndim(), "-D");
  if (!(array.flags() & py::array::c_style))
    HYB_THROW(ValueError, "expected a C-contiguous array indexed (z, y, x) (numpy.ascontiguousarray makes one; a Fortran-ordered array is (x, y, z) reversed)");
  if (!py::cast<bool>(array.attr("flags").attr("aligned")))
    HYB_THROW(ValueError, "expected an aligned array (array.copy() makes one)");
  const ScalarType type = scalarOf(array.dtype());
  const glm::ivec3 dims(int(array.shape(2)), int(array.shape(1)), int(array.shape(0)));
  if (array.shape(0) > INT32_MAX || array.shape(1) > INT32_MAX || array.shape(2) > INT32_MAX) HYB_THROW(ValueError, "array too large along an axis");
  const std::string source = "numpy array";
  const auto keep = std::make_shared<ArrayKeeper>();
  if (type != ScalarType::UInt32 && type != ScalarType::Int32 && type != ScalarType::Float64) {
    keep->array = array;
    return Volume::borrowing({dims, spacing, type, type}, array.data(), keep, source);
  }
  const size_t count = size_t(array.size());
  ValueScan scan;
  {
    py::gil_scoped_release release;  // the caller's reference keeps the array
    scan = detail::withFileType(type, [&](auto zero) { return scanValues(static_cast<const decltype(zero)*>(array.data()), count, dims); });
  }
  // The copy is a numpy array the scene keeps as it keeps a borrowed one: numpy allocates it without
  // zeroing, in huge pages where the kernel gives them on request (4 KiB page faults cost more than
  // the conversion's arithmetic).
  const ScalarType stored = storedTypeOf(scan);
  const std::vector<py::ssize_t> shape(array.shape(), array.shape() + 3);
  py::array copy = detail::withFileType(stored, [&](auto zero) -> py::array { return py::array_t<decltype(zero)>(shape); });
  void* const target = copy.mutable_data();
  {
    py::gil_scoped_release release;
    detail::withFileType(type, [&](auto from) {
      detail::withFileType(stored, [&](auto to) {
        const auto* in = static_cast<const decltype(from)*>(array.data());
        auto* out = static_cast<decltype(to)*>(target);
#pragma omp parallel for schedule(static)
        for (size_t i = 0; i < count; ++i) out[i] = decltype(to)(in[i]);  // whole numbers exact; fractions rounded to float32
      });
    });
  }
  keep->array = copy;
  return Volume::borrowing({dims, spacing, type, stored}, copy.data(), keep, source);
}

// The image as an (H, W, 4) uint8 array: over @p background, opaque, as the command line's PNG
// holds it; else straight alpha over transparent, or premultiplied.
py::array_t<uint8_t> toArray(const Image& image, bool premultiplied, const std::optional<glm::vec3>& background) {
  py::array_t<uint8_t> out({image.height, image.width, 4});
  if (background) {
    const std::vector<uint8_t> rgba = toRgba8(image, *background);
    std::copy(rgba.begin(), rgba.end(), out.mutable_data());
    return out;
  }
  auto o = out.mutable_unchecked<3>();
  for (int y = 0; y < image.height; ++y)
    for (int x = 0; x < image.width; ++x) {
      glm::vec4 p = glm::clamp(image.at(x, y), glm::vec4(0.0f), glm::vec4(1.0f));
      if (!premultiplied && p.a > 0.0f) p = glm::vec4(glm::min(glm::vec3(p) / p.a, glm::vec3(1.0f)), p.a);
      for (int c = 0; c < 4; ++c) o(y, x, c) = uint8_t(std::lround(p[c] * 255.0f));
    }
  return out;
}

// The frame's report as a dict: the keys and values of `--stats` (FrameReport).
py::dict statsOf(const FrameReport& report) { return py::module_::import("json").attr("loads")(report.json()); }

// Each line of @p text (the command line's warnings) as a Python UserWarning.
void warnLines(const std::string& text) {
  std::istringstream lines(text);
  for (std::string line; std::getline(lines, line);)
    if (!line.empty()) PyErr_WarnEx(PyExc_UserWarning, line.c_str(), 1);
}

class PyScene {
 public:
  explicit PyScene(Scene scene, std::string source) : mSource(std::move(source)) {
    mProgress = std::make_unique<Progress>([this](const std::string&, double) { checkSignals(); });
    mRenderer = std::make_unique<SceneRenderer>(std::move(scene), SceneRenderer::Options{0, mProgress.get(), true});
  }

  py::dict info(const py::object& binsArg) {
    const double bins = numberOf("bins", binsArg, Form::Integer);
    if (!(bins >= 1 && bins <= 4096)) HYB_THROW(ValueError, "bins must be in 1..4096");
    const Scene& s = mRenderer->scene();
    const Volume& v = s.volume;
    py::dict d;
    d["source"] = mSource;
    d["dims"] = py::make_tuple(v.dims().x, v.dims().y, v.dims().z);
    d["shape"] = py::make_tuple(v.dims().z, v.dims().y, v.dims().x);
    d["spacing"] = py::make_tuple(v.spacing().x, v.spacing().y, v.spacing().z);
    d["type"] = scalarName(v.sourceType());
    d["stored_type"] = scalarName(v.storedType());
    d["min"] = v.minValue();
    d["max"] = v.maxValue();
    const PatientFrame& f = v.frame();
    d["origin"] = py::make_tuple(f.origin.x, f.origin.y, f.origin.z);
    py::list rows;
    for (int r = 0; r < 3; ++r) rows.append(py::make_tuple(f.direction[0][r], f.direction[1][r], f.direction[2][r]));
    d["direction"] = py::tuple(rows);
    d["orientation"] = orientationCode(f.direction);
    d["bytes"] = v.sourceBytes();
    d["octree_nodes"] = s.octree.nodes().size();
    d["surfaces"] = mRenderer->surfaceIsos();
    d["text"] = v.toString();
    Histogram h;
    {
      py::gil_scoped_release release;
      const Busy busy(*this);
      h = computeHistogram(v, int(bins));
    }
    d["histogram"] = py::dict(py::arg("counts") = h.counts, py::arg("min") = h.minValue, py::arg("max") = h.maxValue, py::arg("mean") = h.mean,
                              py::arg("stddev") = h.stddev, py::arg("p01") = h.p01, py::arg("p50") = h.p50, py::arg("p99") = h.p99);
    return d;
  }

  /// The samples as numpy holds them, indexed (z, y, x), read-only: a view of the scene's own
  /// samples where it holds them (@p self keeps them alive), else (a scene file read paged) a copy
  /// read from its store.
  static py::array samples(const py::object& self) {
    PyScene& s = self.cast<PyScene&>();
    const Scene& scene = s.mRenderer->scene();
    const Volume& v = scene.volume;
    const std::vector<py::ssize_t> shape = {v.dims().z, v.dims().y, v.dims().x};
    auto make = [&](const auto* data, const py::object& base) {
      using T = std::remove_cv_t<std::remove_pointer_t<decltype(data)>>;
      py::array_t<T> a(shape, data, base);
      a.attr("setflags")(py::arg("write") = false);
      return py::array(a);
    };
    if (v.hasSamples()) return v.visitSamples([&](const auto* data) { return make(data, self); });
    if (!scene.knots) HYB_THROW(RuntimeError, s.mSource, ": the scene holds no samples");
    auto owned = std::make_shared<SampleArray>();
    {
      py::gil_scoped_release release;
      *owned = scene.knots->samples();
    }
    return std::visit([&](const auto& vec) { return make(vec.data(), py::capsule(new std::shared_ptr<SampleArray>(owned), [](void* p) {
                                                            delete static_cast<std::shared_ptr<SampleArray>*>(p);
                                                          })); },
                      *owned);
  }

  /// The 4x4 map from voxel index (x, y, z), the array's axes reversed, to LPS millimetres.
  py::array_t<double> affine() const {
    const Volume& v = mRenderer->scene().volume;
    py::array_t<double> m({py::ssize_t(4), py::ssize_t(4)});
    auto a = m.mutable_unchecked<2>();
    for (int r = 0; r < 4; ++r)
      for (int c = 0; c < 4; ++c) a(r, c) = r == 3 ? (c == 3 ? 1.0 : 0.0) : c == 3 ? v.frame().origin[r] : v.frame().direction[c][r] * v.spacing()[c];
    return m;
  }

  // render()'s meshes: a list of (vertices (N, 3), faces (M, 3), rgba), each checked as a mesh file is.
  static std::vector<UserMesh> meshesOf(const py::object& list) {
    if (!py::isinstance<py::sequence>(list) || py::isinstance<py::str>(list))
      throw py::type_error("meshes: expected a list of (vertices, faces, rgba)");
    std::vector<UserMesh> out;
    const py::sequence items = list.cast<py::sequence>();
    for (size_t k = 0; k < items.size(); ++k) {
      const std::string name = "meshes[" + std::to_string(k) + "]";
      const py::object item = items[k];
      if (!py::isinstance<py::sequence>(item) || py::len(item) != 3) throw py::type_error(name + ": expected (vertices, faces, rgba)");
      const py::sequence t = item.cast<py::sequence>();
      const auto vertices = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(t[0]);
      const auto faces = py::array_t<int64_t, py::array::c_style | py::array::forcecast>::ensure(t[1]);
      const auto rgba = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(t[2]);
      if (!vertices || vertices.ndim() != 2 || vertices.shape(1) != 3) throw ValueError(name + ": vertices must be an (N, 3) array of patient mm");
      if (!faces || faces.ndim() != 2 || faces.shape(1) != 3) throw ValueError(name + ": faces must be an (M, 3) array of vertex indices");
      if (!rgba || rgba.ndim() != 1 || rgba.shape(0) != 4) throw ValueError(name + ": rgba must be 4 numbers in [0, 1]");
      TriangleMesh mesh;
      const double* v = vertices.data();
      for (py::ssize_t i = 0; i < vertices.shape(0); ++i) mesh.vertices.push_back(glm::vec3(float(v[3 * i]), float(v[3 * i + 1]), float(v[3 * i + 2])));
      const int64_t* f = faces.data();
      for (py::ssize_t i = 0; i < 3 * faces.shape(0); ++i)
        if (f[i] < 0 || f[i] > int64_t(UINT32_MAX)) throw ValueError(hyb::detail::concat(name, ": triangle ", i / 3, " uses vertex ", f[i], " (expected indices below ", mesh.vertices.size(), ")"));
      for (py::ssize_t i = 0; i < faces.shape(0); ++i) mesh.triangles.push_back(glm::uvec3(uint32_t(f[3 * i]), uint32_t(f[3 * i + 1]), uint32_t(f[3 * i + 2])));
      checkUserMesh(mesh, name);
      const double* c = rgba.data();
      out.push_back(UserMesh{name, std::make_shared<const TriangleMesh>(std::move(mesh)), glm::vec4(float(c[0]), float(c[1]), float(c[2]), float(c[3])), nullptr});
    }
    return out;
  }

  static bool sameMesh(const TriangleMesh& a, const TriangleMesh& b) { return a.vertices == b.vertices && a.triangles == b.triangles; }

  py::object render(const py::kwargs& kwargs) {
    // Each keyword is a field of the one table (render/frame_settings.h), its Python form spelled as
    // the flag's text and parsed by the field, so the messages are the command line's; tf,
    // premultiplied and stats are Python's own; None is a keyword left out.
    bool premultiplied = false, withStats = false;
    FrameSettings settings;
    for (const auto& [k, v] : kwargs) {
      const std::string key = py::cast<std::string>(k);
      const FrameField* field = frameField(key);
      if ((!field || !(field->doors & kPython)) && key != "premultiplied" && key != "stats" && key != "meshes")
        throw py::type_error(hyb::detail::concat("render() got an unexpected keyword argument '", key, "'"));
      if (v.is_none()) continue;
      if (key == "meshes") {
        continue;  // read after the frame is set up
      } else if (key == "premultiplied") {
        premultiplied = flagOf(key, v);
      } else if (key == "stats") {
        withStats = flagOf(key, v);
      } else if (key == "tf" && !pathText(v)) {
        settings.tfPoints = transferFunctionOf(v).points();
      } else if (field->kind == FieldKind::Flag) {
        field->parse(settings, flagOf(key, v) ? "on" : "off", field->flag());
      } else {
        field->parse(settings, spelled(key, v, formOf(*field)), field->flag());
      }
    }
    if (const std::string e = settings.validate(); !e.empty()) throw ValueError(e);
    // --background composites the image over it, opaque, as the command line's PNG holds it.
    const bool composited = kwargs.contains("background") && !kwargs["background"].is_none();
    if (composited && premultiplied) throw ValueError("premultiplied and background are exclusive (a composited image is opaque)");
    std::ostringstream warnings;
    // The same mesh files and primitives as a render before give the same meshes, whose
    // scan-converted channel the renderer keeps (as the viewer's frames do).
    FrameSetup job = setUpFrame(settings, mRenderer->scene(), warnings, &mGeometry);
    if (kwargs.contains("meshes") && !kwargs["meshes"].is_none()) {
      std::vector<UserMesh> arrays = meshesOf(kwargs["meshes"]);
      for (size_t k = 0; k < arrays.size(); ++k) {
        UserMesh& m = arrays[k];
        // Arrays holding the last render's k-th mesh give its object again.
        if (k < mArrayMeshes.size() && sameMesh(*mArrayMeshes[k].mesh, *m.mesh) && mArrayMeshes[k].color == m.color) m = mArrayMeshes[k];
        else
          for (const std::string& w : userMeshWarnings(m, mRenderer->scene().volume)) warnings << "hybrid-octree: warning: " << w << "\n";
        job.look.meshes.push_back(m);
      }
      mArrayMeshes = std::move(arrays);
      if (const std::string e = job.look.validate(); !e.empty()) throw ValueError(e);
    }
    warnLines(warnings.str());
    RenderedFrame frame;
    {
      py::gil_scoped_release release;
      const Busy busy(*this);
      try {
        frame = mRenderer->render(job.view, job.look, job.quality);
      } catch (const Interrupted&) {
        py::gil_scoped_acquire gil;
        throw py::error_already_set();
      }
    }
    if (PyErr_Occurred()) throw py::error_already_set();  // a signal seen as the frame ended
    if (settings.marker) drawOrientationMarker(job.view.camera, &frame.image);
    py::array_t<uint8_t> image = toArray(frame.image, premultiplied, composited ? std::optional(job.background) : std::nullopt);
    if (!withStats) return image;
    return py::make_tuple(image, statsOf(FrameReport{frame, job.quality, job.view.camera, mRenderer->scene().knots.get(), frame.stats.renderMs,
                                                     frame.stats.preintegrationMs, frame.stats.geometryMs}));
  }

  py::tuple surface(const py::object& iso, const py::object& kind, const py::object& closed, const py::object& normals) {
    const MeshRequest r(iso, kind, closed, normals);
    const ExportedSurface e = exported(r);
    const TriangleMesh& m = e.mesh;
    py::array_t<float> vertices({py::ssize_t(m.vertices.size()), py::ssize_t(3)});
    py::array_t<int64_t> faces({py::ssize_t(m.triangles.size()), py::ssize_t(3)});
    if (!m.vertices.empty()) std::copy_n(&m.vertices.front().x, 3 * m.vertices.size(), vertices.mutable_data());
    auto f = faces.mutable_unchecked<2>();
    for (size_t t = 0; t < m.triangles.size(); ++t)
      for (int k = 0; k < 3; ++k) f(py::ssize_t(t), k) = int64_t(m.triangles[t][k]);
    if (!r.normals) return py::make_tuple(vertices, faces);
    py::array_t<float> n({py::ssize_t(m.normals.size()), py::ssize_t(3)});
    if (!m.normals.empty()) std::copy_n(&m.normals.front().x, 3 * m.normals.size(), n.mutable_data());
    return py::make_tuple(vertices, faces, n);
  }

  void exportMesh(const py::object& pathArg, const py::object& iso, const py::object& kind, const py::object& closed, const py::object& normals) {
    const std::string path = spelled("path", pathArg, Form::Word);
    const MeshRequest r(iso, kind, closed, normals);
    const MeshFormat* format = meshFormatOf(path);
    if (!format) HYB_THROW(ValueError, "'", path, "' has an unknown extension (expected ", meshExtensionsText(), ")");
    if (r.normals && !format->normals) HYB_THROW(ValueError, "normals need a ", meshExtensionsText(true), " file (STL keeps facet normals, OFF none)");
    const ExportedSurface e = exported(r);
    py::gil_scoped_release release;
    writeMesh(path, e.mesh, MeshWriteOptions{r.normals, "LPS"});
  }

  /// Builds the isosurface of @p iso now and keeps it for frames (Scene(iso=...)).
  void prepareSurface(const py::object& isoArg) {
    const float iso = isoOf(isoArg);
    py::gil_scoped_release release;
    const Busy busy(*this);
    mRenderer->surface(iso, SurfaceNormals::Gradient);
  }

 private:
  // One call at a time on a scene's engine (not thread-safe): a second thread waits; a call from
  // inside a frame (a signal handler's) is refused rather than deadlocking.
  struct Busy {
    PyScene& s;
    explicit Busy(PyScene& scene) : s(scene) {
      if (s.mOwner.load() == std::this_thread::get_id()) HYB_THROW(RuntimeError, "the scene is drawing a frame on this thread (from a signal handler?)");
      s.mMutex.lock();
      s.mOwner = std::this_thread::get_id();
    }
    ~Busy() {
      s.mOwner = std::thread::id();
      s.mMutex.unlock();
    }
  };

  static float isoOf(const py::handle& v) {
    const double iso = numberOf("iso", v);
    if (!isFloat(iso)) HYB_THROW(ValueError, "iso must be a finite number within the float range (|x| <= 3.4e38)");
    return float(iso);
  }

  // surface() and export()'s keywords, in their types.
  struct MeshRequest {
    float iso;
    std::string kind;
    bool closed, normals;
    MeshRequest(const py::handle& isoArg, const py::handle& kindArg, const py::handle& closedArg, const py::handle& normalsArg)
        : iso(isoOf(isoArg)), kind(spelled("kind", kindArg, Form::Word)), closed(flagOf("closed", closedArg)), normals(flagOf("normals", normalsArg)) {}
  };

  // render()'s keywords beside tf, premultiplied and stats: the command line's flags (`-` as `_`)
  // and how each is written in Python.
  ExportedSurface exported(const MeshRequest& r) {
    std::ostringstream out;
    py::gil_scoped_release release;
    const Busy busy(*this);
    return exportSurface(mRenderer->scene(), ExportRequest{r.iso, r.kind, r.closed, r.normals, false}, nullptr, out);
  }

  static TransferFunction transferFunctionOf(const py::handle& v) {
    const auto a = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(v);
    if (!a || a.ndim() == 0) throw py::type_error(hyb::detail::concat("tf must be an (N, 5) array of numbers or a transfer-function file's path, got ", Py_TYPE(v.ptr())->tp_name));
    if (a.ndim() != 2 || a.shape(1) != 5)
      HYB_THROW(ValueError, "tf must be an (N, 5) array of control points: value, r, g, b, opacity per mm");
    std::vector<TransferFunction::Point> points;
    const auto r = a.unchecked<2>();
    for (py::ssize_t i = 0; i < a.shape(0); ++i)
      points.push_back({float(r(i, 0)), glm::vec3(float(r(i, 1)), float(r(i, 2)), float(r(i, 3))), float(r(i, 4))});
    return TransferFunction(std::move(points), "array");
  }

  // From the frame's progress (the rendering thread, the GIL released): a pending signal's
  // exception (KeyboardInterrupt) stops the frame. Only the main thread runs signal handlers.
  static void checkSignals() {
    py::gil_scoped_acquire gil;
    if (PyErr_CheckSignals() != 0) throw Interrupted();
  }

  std::string mSource;
  std::mutex mMutex;
  std::atomic<std::thread::id> mOwner{};
  std::unique_ptr<Progress> mProgress;
  std::unique_ptr<SceneRenderer> mRenderer;
  UserGeometryMemo mGeometry;           ///< render()'s mesh files and primitives (under the GIL)
  std::vector<UserMesh> mArrayMeshes;   ///< the last render()'s meshes= arrays
};

std::unique_ptr<PyScene> sceneFromArray(const py::object& array, const py::object& spacing, const py::object& origin, const py::object& direction,
                                        const py::object& iso) {
  const glm::dvec3 sp = spacing.is_none() ? glm::dvec3(1.0) : parseVec3(spelled("spacing", spacing, Form::Numbers), "spacing");
  validateSpacing(sp, "spacing");  // before a conversion's passes over the samples
  PatientFrame frame;
  if (!origin.is_none()) frame.origin = parseVec3(spelled("origin", origin, Form::Numbers), "origin");
  if (!direction.is_none()) {
    const auto d = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(direction);
    if (!d || py::isinstance<py::str>(direction))
      throw py::type_error(hyb::detail::concat("direction must be a 3x3 matrix of numbers, got ", Py_TYPE(direction.ptr())->tp_name));
    if (d.size() != 9) HYB_THROW(ValueError, "direction must be a 3x3 matrix (or 9 numbers, row by row) whose columns are the x, y and z axes in LPS");
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) frame.direction[c][r] = d.data()[3 * r + c];
    const glm::dmat3 dd = frame.direction;
    const glm::dmat3 gram = glm::transpose(dd) * dd;
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c)
        if (!(std::abs(gram[c][r] - (r == c ? 1.0 : 0.0)) < 1e-4)) HYB_THROW(ValueError, "direction must be orthonormal (its columns unit and perpendicular)");
  }
  Volume volume = volumeOf(array, sp);
  volume.setFrame(frame);
  Scene scene;
  {
    py::gil_scoped_release release;
    scene.octree = VolumeOctree::build(volume);
  }
  scene.volume = std::move(volume);
  auto s = std::make_unique<PyScene>(std::move(scene), "numpy array");
  if (!iso.is_none()) s->prepareSurface(iso);
  return s;
}

std::unique_ptr<PyScene> openPath(const py::object& pathArg, const py::object& seriesArg) {
  const std::string path = spelled("path", pathArg, Form::Word);
  const std::string series = seriesArg.is_none() ? std::string() : spelled("series", seriesArg, Form::Word);
  OpenedScene o;
  {
    py::gil_scoped_release release;
    SceneSource source;
    source.path = path;
    source.series = series;
    o = openScene(source);
  }
  if (!o.loaded)
    for (const std::string& w : o.scene.volume.warnings()) warnLines("hybrid-octree: warning: " + w + "\n");
  return std::make_unique<PyScene>(std::move(o.scene), path);
}

}  // namespace
}  // namespace hyb::app

PYBIND11_MODULE(hybrid_octree, m) {
  using namespace hyb::app;
  m.doc() = "hybrid-octree: CT volumes with embedded isosurfaces, rendered and meshed (numpy in, images and meshes out)";
  py::register_exception_translator([](std::exception_ptr p) {
    try {
      if (p) std::rethrow_exception(p);
    } catch (const hyb::ValueError& e) {
      PyErr_SetString(PyExc_ValueError, e.what());
    } catch (const hyb::IoError& e) {
      PyErr_SetString(PyExc_OSError, e.what());
    } catch (const hyb::RuntimeError& e) {
      PyErr_SetString(PyExc_RuntimeError, e.what());
    }
  });
  py::class_<PyScene>(m, "Scene")
      .def(py::init(&sceneFromArray), py::arg("array"), py::arg("spacing") = py::none(), py::arg("origin") = py::none(),
           py::arg("direction") = py::none(), py::arg("iso") = py::none())
      .def_property_readonly("array", &PyScene::samples,
                             "the samples (z, y, x), read-only: a view of the scene's own where it holds them, else a copy")
      .def_property_readonly("affine", &PyScene::affine, "4x4: voxel index (x, y, z) to LPS mm, as ITK's and the command line's frame")
      .def("info", &PyScene::info, py::arg("bins") = 24)
      .def("render", &PyScene::render)
      .def("surface", &PyScene::surface, py::arg("iso"), py::arg("kind") = "octree", py::arg("closed") = false, py::arg("normals") = false)
      .def("export", &PyScene::exportMesh, py::arg("path"), py::arg("iso"), py::arg("kind") = "dmc", py::arg("closed") = false,
           py::arg("normals") = false);
  m.def("open", &openPath, py::arg("path"), py::arg("series") = py::none());
  m.def(
      "frame_fields", [] { return py::module_::import("json").attr("loads")(hyb::fieldsJson(hyb::kPython).dump()); },
      "render()'s keywords as the one table of a frame's settings holds them: name, kind, range, default, unit, help");
}
