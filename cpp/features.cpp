// Surface normals and FPFH descriptors (pcl_features, thesis 3.3.2).
#include <pcl/features/fpfh_omp.h>
#include <pcl/features/normal_3d_omp.h>

#include <dlfcn.h>

#include <cmath>
#include <string>

#include "binpick-pcl/src/ffi.rs.h"
#include "internal.h"

// The classes this module shares with the reference pipeline, compiled here once (internal.h).
BINPICK_FEATURES_TEMPLATES(BINPICK_INSTANTIATE_TEMPLATE)

// The bridge compiles PCL's class templates from PCL's own headers (PCL_NO_PRECOMPILE, build.rs)
// instead of linking Debian's libpcl_features, whose 117 000 symbol relocations cost every
// process ~60 ms at start whether or not a feature is computed. The one function of that library
// the templates call that is not a template, pcl::computePairFeatures (features/src/pfh.cpp,
// used by FPFH), is PCL's own, looked up in libpcl_features when FPFH first runs.
namespace {

using PairFeaturesFn = bool (*)(const Eigen::Vector4f&, const Eigen::Vector4f&,
                                const Eigen::Vector4f&, const Eigen::Vector4f&, float&, float&,
                                float&, float&);

constexpr const char* kFeaturesLibrary = "libpcl_features.so.1.13";
constexpr const char* kPairFeaturesSymbol =
    "_ZN3pcl19computePairFeaturesERKN5Eigen6MatrixIfLi4ELi1ELi0ELi4ELi1EEES4_S4_S4_RfS5_S5_S5_";

struct PairFeatures {
  PairFeaturesFn fn = nullptr;
  std::string error;
};

// Looked up once (thread-safe static); the library stays loaded for the process.
const PairFeatures& pair_features() {
  static const PairFeatures found = [] {
    PairFeatures out;
    void* library = dlopen(kFeaturesLibrary, RTLD_NOW | RTLD_LOCAL);
    if (library == nullptr) {
      const char* why = dlerror();
      out.error = std::string("cannot load ") + kFeaturesLibrary + " (PCL's features library: " +
                  (why ? why : "unknown error") + "); install libpcl-dev or run ./scripts/setup";
      return out;
    }
    out.fn = reinterpret_cast<PairFeaturesFn>(dlsym(library, kPairFeaturesSymbol));
    if (out.fn == nullptr) {
      out.error = std::string(kFeaturesLibrary) + " has no pcl::computePairFeatures";
    }
    return out;
  }();
  return found;
}

}  // namespace

namespace pcl {

// Forwards to PCL's own definition. Never reached before `require_pair_features` has found it
// (the FPFH entry points call that first, outside any OpenMP region, so a missing library is an
// error across the bridge, not a throw inside FPFHEstimationOMP's parallel loop).
bool computePairFeatures(const Eigen::Vector4f& p1, const Eigen::Vector4f& n1,
                         const Eigen::Vector4f& p2, const Eigen::Vector4f& n2, float& f1,
                         float& f2, float& f3, float& f4) {
  const PairFeaturesFn fn = pair_features().fn;
  if (fn == nullptr) std::abort();  // unreachable: see require_pair_features
  return fn(p1, n1, p2, n2, f1, f2, f3, f4);
}

}  // namespace pcl

namespace binpick {

void require_pair_features() {
  const auto& found = pair_features();
  if (found.fn == nullptr) throw std::runtime_error(found.error);
}

namespace {

using Normals = pcl::PointCloud<pcl::Normal>;

Eigen::Vector3f read_viewpoint(rust::Slice<const float> viewpoint) {
  if (viewpoint.size() != 3 || !std::isfinite(viewpoint[0]) || !std::isfinite(viewpoint[1]) ||
      !std::isfinite(viewpoint[2])) {
    fail("viewpoint must be 3 finite coordinates");
  }
  return {viewpoint[0], viewpoint[1], viewpoint[2]};
}

// pcl::NormalEstimationOMP over `cloud`, searching `tree` (built on `cloud`), flipped towards
// the sensor viewpoint so the model and the scene orient normals the same way.
// With `at`, only at those points (indices into `cloud`), the whole cloud still searched.
Normals::Ptr normals_for(const PointCloudXYZ::Ptr& cloud,
                         const pcl::search::Search<pcl::PointXYZ>::Ptr& tree, float radius,
                         const Eigen::Vector3f& vp, std::uint32_t threads,
                         const pcl::IndicesPtr& at = nullptr) {
  pcl::NormalEstimationOMP<pcl::PointXYZ, pcl::Normal> ne(threads);
  ne.setInputCloud(cloud);
  if (at) ne.setIndices(at);
  ne.setSearchMethod(tree);
  ne.setRadiusSearch(radius);
  ne.setViewPoint(vp.x(), vp.y(), vp.z());
  Normals::Ptr normals(new Normals);
  ne.compute(*normals);
  if (normals->size() != (at ? at->size() : cloud->size())) {
    throw std::runtime_error("NormalEstimationOMP failed (see PCL's message above)");
  }
  return normals;
}

rust::Vec<float> flatten_normals(const Normals& normals) {
  rust::Vec<float> out;
  out.reserve(normals.size() * 4);
  for (const auto& n : normals.points) {
    out.push_back(n.normal_x);
    out.push_back(n.normal_y);
    out.push_back(n.normal_z);
    out.push_back(n.curvature);
  }
  return out;
}

}  // namespace

rust::Vec<float> estimate_normals(rust::Slice<const float> xyz, float radius,
                                  rust::Slice<const float> viewpoint, std::uint32_t threads) {
  check_positive(radius, "normal radius");
  const auto vp = read_viewpoint(viewpoint);
  const auto cloud = to_cloud(xyz, "estimate_normals");
  return flatten_normals(*normals_for(cloud, make_tree(cloud), radius, vp, threads));
}

rust::Vec<float> estimate_normals_at(rust::Slice<const float> xyz,
                                     rust::Slice<const std::uint32_t> at, float radius,
                                     rust::Slice<const float> viewpoint, std::uint32_t threads) {
  check_positive(radius, "normal radius");
  const auto vp = read_viewpoint(viewpoint);
  const auto cloud = to_cloud(xyz, "estimate_normals_at");
  auto indices = std::make_shared<pcl::Indices>(to_indices(at, cloud->size(), "normal points"));
  if (indices->empty()) return {};
  return flatten_normals(*normals_for(cloud, make_tree(cloud), radius, vp, threads, indices));
}

// estimate_normals_at over an uploaded cloud, searching the kd-tree built on upload: the
// tree estimate_normals_at would build (make_tree over the same points), so the same normals.
rust::Vec<float> cloud_normals_at(const Cloud& cloud, rust::Slice<const std::uint32_t> at,
                                  float radius, rust::Slice<const float> viewpoint,
                                  std::uint32_t threads) {
  check_positive(radius, "normal radius");
  const auto vp = read_viewpoint(viewpoint);
  const auto& s = cloud.impl();
  auto indices = std::make_shared<pcl::Indices>(to_indices(at, s.points->size(), "normal points"));
  if (indices->empty()) return {};
  return flatten_normals(*normals_for(s.points, s.tree, radius, vp, threads, indices));
}

// FPFH (pcl::FPFHEstimationOMP) at `keypoints` (indices into `surface`), with the whole
// surface as search surface: normals are estimated on the surface at `normal_radius`
// (thesis: 0.8 x feature radius), then the descriptor at `feature_radius`. The surface's
// kd-tree, built once on upload, serves both estimators (through its neighbourhood cache when
// the upload built one that covers the radius). A keypoint whose descriptor is
// undefined (no neighbours, or an undefined normal) is marked invalid instead of carrying
// NaNs into the feature kd-tree.
Features cloud_fpfh(const Cloud& surface, rust::Slice<const std::uint32_t> keypoints,
                    float feature_radius, float normal_radius, rust::Slice<const float> viewpoint,
                    std::uint32_t threads) {
  check_positive(feature_radius, "FPFH radius");
  check_positive(normal_radius, "normal radius");
  const auto vp = read_viewpoint(viewpoint);
  const auto& s = surface.impl();
  auto indices = std::make_shared<pcl::Indices>(to_indices(keypoints, s.points->size(), "keypoints"));
  if (indices->empty()) fail("cloud_fpfh: no keypoints");
  require_pair_features();

  const auto normals =
      normals_for(s.points, radius_search_method(s, normal_radius), normal_radius, vp, threads);

  pcl::FPFHEstimationOMP<pcl::PointXYZ, pcl::Normal, pcl::FPFHSignature33> fpfh(threads);
  fpfh.setInputCloud(s.points);
  fpfh.setIndices(indices);
  fpfh.setInputNormals(normals);
  fpfh.setSearchMethod(radius_search_method(s, feature_radius));
  fpfh.setRadiusSearch(feature_radius);
  pcl::PointCloud<pcl::FPFHSignature33> descriptors;
  fpfh.compute(descriptors);
  if (descriptors.size() != indices->size()) {
    throw std::runtime_error("FPFHEstimationOMP failed (see PCL's message above)");
  }

  Features out;
  out.values.reserve(descriptors.size() * 33);
  out.valid.reserve(descriptors.size());
  for (std::size_t k = 0; k < descriptors.size(); ++k) {
    const auto& h = descriptors[k].histogram;
    const auto& n = (*normals)[(*indices)[k]];
    bool ok = std::isfinite(n.normal_x) && std::isfinite(n.normal_y) && std::isfinite(n.normal_z);
    for (int d = 0; d < 33; ++d) {
      ok = ok && std::isfinite(h[d]);
      out.values.push_back(h[d]);
    }
    out.valid.push_back(ok);
  }
  return out;
}

}  // namespace binpick
