// The Python module `hybrid_octree` (pybind11): numpy volumes in without copying their samples,
// images and meshes out, through the engine the command line uses. Rendering options are the
// command line's flags as keyword arguments, parsed and checked by the same code, so a mistake gets
// the command line's message. README "Python"; the API with types: apps/hybrid_octree.pyi.
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <Python.h>

#include <algorithm>
#include <cmath>
#include <atomic>
#include <mutex>
#include <set>
#include <thread>
#include <sstream>

#include "apps/frame.h"
#include "hybrid_octree/hybrid_io.h"
#include "render/orientation_marker.h"
#include "surface/mesh_io.h"
#include "volume/error.h"
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

glm::dvec3 vec3Of(const py::handle& h, const char* what) {
  std::vector<double> v;
  try {
    v = py::cast<std::vector<double>>(h);
  } catch (const py::cast_error&) {
    throw py::type_error(hyb::detail::concat(what, " must be three numbers"));
  }
  if (v.size() != 3) HYB_THROW(ValueError, what, " must be three numbers, got ", v.size());
  for (const double x : v)
    if (!std::isfinite(x)) HYB_THROW(ValueError, what, " must be finite");
  return {v[0], v[1], v[2]};
}

// A volume over @p array's samples: borrowed when held in their own type, else converted to the
// type the readers hold them in (32-bit integers and float64: int16, uint16 or float32).
Volume volumeOf(const py::array& array, const glm::dvec3& spacing) {
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
  switch (type) {
    case ScalarType::UInt8:
    case ScalarType::Int8:
    case ScalarType::UInt16:
    case ScalarType::Int16:
    case ScalarType::Float32: {
      auto keep = std::make_shared<ArrayKeeper>();
      keep->array = array;
      return Volume::borrowing(dims, spacing, type, type, array.data(), std::move(keep), source);
    }
    default: {
      // As a reader of these types does: a copy, into 16 bits when the values fit, else float.
      SampleArray samples = detail::decodeSamples(static_cast<const uint8_t*>(array.data()), size_t(array.size()), type, false);
      return Volume(dims, spacing, type, std::move(samples), source);
    }
  }
}

std::string flagValue(const py::handle& v) {
  if (py::isinstance<py::str>(v)) return py::cast<std::string>(v);
  if (py::isinstance<py::bool_>(v)) return py::cast<bool>(v) ? "on" : "off";
  if (py::isinstance<py::array>(v) && py::cast<py::array>(v).ndim() == 0) return flagValue(v.attr("item")());
  if (!py::hasattr(v, "__iter__") && PyNumber_Check(v.ptr())) {  // Python's and numpy's numbers
    std::ostringstream s;
    s.precision(17);
    s << py::cast<double>(v);
    return s.str();
  }
  // Sequences of numbers: "a,b,c".
  std::string out;
  for (const py::handle x : py::iter(v)) out += (out.empty() ? "" : ",") + flagValue(x);
  return out;
}

py::array_t<uint8_t> toArray(const Image& image, bool premultiplied) {
  py::array_t<uint8_t> out({image.height, image.width, 4});
  auto o = out.mutable_unchecked<3>();
  for (int y = 0; y < image.height; ++y)
    for (int x = 0; x < image.width; ++x) {
      glm::vec4 p = glm::clamp(image.at(x, y), glm::vec4(0.0f), glm::vec4(1.0f));
      if (!premultiplied && p.a > 0.0f) p = glm::vec4(glm::min(glm::vec3(p) / p.a, glm::vec3(1.0f)), p.a);
      for (int c = 0; c < 4; ++c) o(y, x, c) = uint8_t(std::lround(p[c] * 255.0f));
    }
  return out;
}

py::dict statsOf(const RenderedFrame& f) {
  const FrameStats& s = f.stats;
  py::dict d;
  d["renderer"] = s.renderer == Renderer::Slices ? "slices" : "raycast";
  d["render_ms"] = s.renderMs;
  d["select_ms"] = s.selectMs;
  d["bricks"] = f.selection.bricks.size();
  d["textured_bricks"] = s.slices.bricks;
  d["texels"] = f.selection.texels;
  d["texture_bytes"] = s.slices.textureBytes;
  d["slices"] = s.slices.slices;
  d["surface_triangles"] = s.surfaceTriangles;
  d["slab_polygon_draws"] = s.slices.slabPolygonDraws;
  d["rays"] = s.rays.rays;
  d["samples"] = s.rays.samples;
  d["max_nodal_error_used"] = f.selection.maxError;
  d["budget_met"] = f.selection.budgetMet;
  d["preintegration_ms"] = s.preintegrationMs;
  return d;
}

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

  py::dict info(int bins) {
    if (bins < 1 || bins > 4096) HYB_THROW(ValueError, "bins must be in 1..4096");
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
      h = computeHistogram(v, bins);
    }
    d["histogram"] = py::dict(py::arg("counts") = h.counts, py::arg("min") = h.minValue, py::arg("max") = h.maxValue, py::arg("mean") = h.mean,
                              py::arg("stddev") = h.stddev, py::arg("p01") = h.p01, py::arg("p50") = h.p50, py::arg("p99") = h.p99);
    return d;
  }

  py::object render(const py::kwargs& kwargs) {
    // The command line's flags, from the keywords (tf, premultiplied and stats are Python's own).
    bool premultiplied = false, withStats = false;
    std::optional<TransferFunction> tf;
    std::vector<std::string> args;
    for (const auto& [k, v] : kwargs) {
      const std::string key = py::cast<std::string>(k);
      if (key == "premultiplied") {
        premultiplied = py::cast<bool>(v);
      } else if (key == "stats") {
        withStats = py::cast<bool>(v);
      } else if (key == "tf") {
        tf = transferFunctionOf(v);
      } else if (key == "ortho") {
        if (py::cast<bool>(v)) args.push_back("--ortho");
      } else if (key == "size") {
        const std::vector<int> wh = py::cast<std::vector<int>>(v);
        if (wh.size() != 2) HYB_THROW(ValueError, "size must be (width, height)");
        args.push_back("--size=" + std::to_string(wh[0]) + "x" + std::to_string(wh[1]));
      } else if (key == "budget" && !py::isinstance<py::str>(v)) {
        args.push_back("--budget=" + flagValue(v));
      } else if (kAllowed.count(key)) {
        std::string flag = key;
        std::replace(flag.begin(), flag.end(), '_', '-');
        args.push_back("--" + flag + "=" + flagValue(v));
      } else {
        throw py::type_error(hyb::detail::concat("render() got an unexpected keyword argument '", key, "'"));
      }
    }
    RenderOptions o;
    CLI::App app("render", "render");
    o.add(&app);
    std::vector<std::string> reversed(args.rbegin(), args.rend());
    try {
      app.parse(reversed);
    } catch (const CLI::ParseError& e) {
      HYB_THROW(ValueError, e.what());
    }
    if (const std::string e = o.validate(); !e.empty() && e.rfind("-o", 0) != 0) throw ValueError(e);
    RenderJob job;
    std::ostringstream warnings;
    setUpFrame(o, mRenderer->scene(), &job, warnings, tf ? &*tf : nullptr);
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
    if (o.marker) drawOrientationMarker(job.view.camera, &frame.image);
    py::array_t<uint8_t> image = toArray(frame.image, premultiplied);
    if (!withStats) return image;
    return py::make_tuple(image, statsOf(frame));
  }

  py::tuple surface(double iso, const std::string& kind, bool closed, bool normals) {
    const ExportedSurface e = exported(iso, kind, closed, normals);
    const TriangleMesh& m = e.mesh;
    py::array_t<float> vertices({py::ssize_t(m.vertices.size()), py::ssize_t(3)});
    py::array_t<int64_t> faces({py::ssize_t(m.triangles.size()), py::ssize_t(3)});
    if (!m.vertices.empty()) std::copy_n(&m.vertices.front().x, 3 * m.vertices.size(), vertices.mutable_data());
    auto f = faces.mutable_unchecked<2>();
    for (size_t t = 0; t < m.triangles.size(); ++t)
      for (int k = 0; k < 3; ++k) f(py::ssize_t(t), k) = int64_t(m.triangles[t][k]);
    if (!normals) return py::make_tuple(vertices, faces);
    py::array_t<float> n({py::ssize_t(m.normals.size()), py::ssize_t(3)});
    if (!m.normals.empty()) std::copy_n(&m.normals.front().x, 3 * m.normals.size(), n.mutable_data());
    return py::make_tuple(vertices, faces, n);
  }

  void exportMesh(const std::string& path, double iso, const std::string& kind, bool closed, bool normals) {
    const std::string ext = fileExtension(path);
    if (ext != ".ply" && ext != ".obj" && ext != ".stl" && ext != ".off")
      HYB_THROW(ValueError, "'", path, "' has an unknown extension (expected .ply, .obj, .stl or .off)");
    if (normals && ext != ".ply" && ext != ".obj") HYB_THROW(ValueError, "normals need a .ply or .obj file (STL keeps facet normals, OFF none)");
    const ExportedSurface e = exported(iso, kind, closed, normals);
    py::gil_scoped_release release;
    writeMesh(path, e.mesh, MeshWriteOptions{normals, "LPS"});
  }

  /// Builds the isosurface of @p iso now and keeps it for frames (Scene(iso=...)).
  void prepareSurface(double iso) {
    checkIso(iso);
    py::gil_scoped_release release;
    const Busy busy(*this);
    mRenderer->surface(float(iso), SurfaceNormals::Gradient);
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

  static void checkIso(double iso) {
    if (!std::isfinite(iso) || std::abs(iso) > 3.4e38) HYB_THROW(ValueError, "iso must be a finite number within the float range");
  }

  static inline const std::set<std::string> kAllowed = {
      "view", "orbit", "eye", "center", "up", "zoom", "fov", "preset", "iso", "surface_color", "surface_normals", "shading", "cut", "cut_line",
      "voi", "voi_inside", "voi_outside", "voi_ramp", "renderer", "epsilon", "budget", "step", "classification", "proxy", "blend", "lod_pixels",
      "max_brick", "texel_bits", "focus", "camera_file", "marker", "image_scale"};

  ExportedSurface exported(double iso, const std::string& kind, bool closed, bool normals) {
    checkIso(iso);
    std::ostringstream out;
    py::gil_scoped_release release;
    const Busy busy(*this);
    return exportedSurface(mRenderer->scene(), float(iso), kind, closed, normals, false, nullptr, out);
  }

  static TransferFunction transferFunctionOf(const py::handle& v) {
    const py::array_t<double, py::array::c_style | py::array::forcecast> a = py::cast<py::array>(v);
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
};

std::unique_ptr<PyScene> sceneFromArray(const py::array& array, const py::object& spacing, const py::object& origin, const py::object& direction,
                                        const py::object& iso) {
  const glm::dvec3 sp = spacing.is_none() ? glm::dvec3(1.0) : vec3Of(spacing, "spacing");
  Volume volume = volumeOf(array, sp);
  PatientFrame frame;
  if (!origin.is_none()) frame.origin = vec3Of(origin, "origin");
  if (!direction.is_none()) {
    const py::array_t<double, py::array::c_style | py::array::forcecast> d = py::cast<py::array>(direction);
    if (d.size() != 9) HYB_THROW(ValueError, "direction must be a 3x3 matrix (or 9 numbers, row by row) whose columns are the x, y and z axes in LPS");
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) frame.direction[c][r] = d.data()[3 * r + c];
    const glm::dmat3 dd = frame.direction;
    const glm::dmat3 gram = glm::transpose(dd) * dd;
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c)
        if (!(std::abs(gram[c][r] - (r == c ? 1.0 : 0.0)) < 1e-4)) HYB_THROW(ValueError, "direction must be orthonormal (its columns unit and perpendicular)");
  }
  volume.setFrame(frame);
  Scene scene;
  {
    py::gil_scoped_release release;
    scene.octree = VolumeOctree::build(volume);
  }
  scene.volume = std::move(volume);
  auto s = std::make_unique<PyScene>(std::move(scene), "numpy array");
  if (!iso.is_none()) s->prepareSurface(py::cast<double>(iso));
  return s;
}

std::unique_ptr<PyScene> openScene(const std::string& path) {
  VolumeInput in;
  in.path = path;
  std::ostringstream out, err;
  double buildMs = 0;
  Scene scene;
  {
    py::gil_scoped_release release;
    scene = loadOrBuild(in, out, err, &buildMs);
  }
  warnLines(err.str());
  return std::make_unique<PyScene>(std::move(scene), path);
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
      .def("info", &PyScene::info, py::arg("bins") = 24)
      .def("render", &PyScene::render)
      .def("surface", &PyScene::surface, py::arg("iso"), py::arg("kind") = "octree", py::arg("closed") = false, py::arg("normals") = false)
      .def("export", &PyScene::exportMesh, py::arg("path"), py::arg("iso"), py::arg("kind") = "dmc", py::arg("closed") = false,
           py::arg("normals") = false);
  m.def("open", &openScene, py::arg("path"));
}
