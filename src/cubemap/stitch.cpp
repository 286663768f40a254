#include "cubemap/stitch.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <numbers>
#include <numeric>
#include <random>

#include <glm/geometric.hpp>
#include <glm/mat3x3.hpp>
#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>
#include <opencv2/features2d.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/stitching/detail/matchers.hpp>
#include <opencv2/stitching/detail/motion_estimators.hpp>

#include "core/error.h"
#include "core/numbers.h"
#include "core/parallel.h"

namespace compose::cubemap {

using lighting::kCubeFaces;

namespace {

// Verified matches a pair needs. The rotation model has two degrees of freedom per match and the
// rough orientations already bound it, so a handful of agreeing matches is not chance.
constexpr size_t kMinInliers = 8;
// A pair's matched rotation is refused when the log luminance of its overlap disagrees more than
// this many times as much (variance) as under the rough orientations (see matchPair).
constexpr double kMatchedOverRough = 1.5;
// Photo pixels a sub-texel ray may span before the texel is cut into more rays.
constexpr double kSubTexelPixels = 2.0;

double angleBetween(const glm::dvec3& a, const glm::dvec3& b) {
  return std::atan2(glm::length(glm::cross(a, b)), glm::dot(a, b));
}

// Angle of the rotation a^T b.
double rotationAngle(const glm::dmat3& a, const glm::dmat3& b) {
  const glm::dmat3 r = glm::transpose(a) * b;
  const double c = std::clamp((r[0][0] + r[1][1] + r[2][2] - 1.0) * 0.5, -1.0, 1.0);
  return std::acos(c);
}

// The rotation nearest to m (polar decomposition by SVD).
glm::dmat3 nearestRotation(const glm::dmat3& m) {
  cv::Matx33d a;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) a(r, c) = m[c][r];
  cv::Mat w, u, vt;
  cv::SVD::compute(cv::Mat(a), w, u, vt);
  cv::Mat rot = u * vt;
  if (cv::determinant(rot) < 0) {
    cv::Mat d = cv::Mat::eye(3, 3, CV_64F);
    d.at<double>(2, 2) = -1.0;
    rot = u * d * vt;
  }
  glm::dmat3 out;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) out[c][r] = rot.at<double>(r, c);
  return out;
}

// The rotation that turns orientations fixed only relative to each other (`refined`) as a whole to
// where the photos' rough orientations (`rough`, the same photos in the same order) say they are:
// the one nearest to Σ rough_k refined_kᵀ.
glm::dmat3 towardsRough(const std::vector<glm::dmat3>& rough,
                        const std::vector<glm::dmat3>& refined) {
  glm::dmat3 m(0.0);
  for (size_t k = 0; k < rough.size(); ++k) m += rough[k] * glm::transpose(refined[k]);
  return nearestRotation(m);
}

// Rotation q minimising Σ |q a_k - b_k|² (Kabsch).
glm::dmat3 kabsch(const std::vector<glm::dvec3>& a, const std::vector<glm::dvec3>& b) {
  glm::dmat3 m(0.0);  // Σ b a^T
  for (size_t k = 0; k < a.size(); ++k) m += glm::outerProduct(b[k], a[k]);
  return nearestRotation(m);
}

// Area-averaged mip pyramid of a photo (RGB float), for prefiltered lookups.
// Distance in pixels from every pixel to the nearest one that holds no picture: black (0 in
// every channel) and joined to the frame's border through black pixels, as outside a circular
// fisheye's image circle or in the corners a lens correction left. Empty when no such pixel is
// there (a black part inside the frame is the scene's).
cv::Mat distanceToNoPicture(const Image& img) {
  const int w = img.width, h = img.height, c = img.channels;
  cv::Mat black(h, w, CV_8U);
  parallelFor(0, h, [&](int64_t y) {
    const float* p = img.row(int(y)).data();
    uint8_t* m = black.ptr<uint8_t>(int(y));
    for (int x = 0; x < w; ++x, p += c) m[x] = (p[0] <= 0.0f && p[1] <= 0.0f && p[2] <= 0.0f);
  });
  // Most photos have no black pixel on their border: nothing to label.
  bool onBorder = false;
  for (int x = 0; x < w && !onBorder; ++x)
    onBorder = black.at<uint8_t>(0, x) || black.at<uint8_t>(h - 1, x);
  for (int y = 0; y < h && !onBorder; ++y)
    onBorder = black.at<uint8_t>(y, 0) || black.at<uint8_t>(y, w - 1);
  if (!onBorder) return {};
  cv::Mat labels;
  const int count = cv::connectedComponents(black, labels, 8, CV_32S);
  std::vector<uint8_t> outer(size_t(count), 0);
  for (int x = 0; x < w; ++x) {
    outer[size_t(labels.at<int>(0, x))] = 1;
    outer[size_t(labels.at<int>(h - 1, x))] = 1;
  }
  for (int y = 0; y < h; ++y) {
    outer[size_t(labels.at<int>(y, 0))] = 1;
    outer[size_t(labels.at<int>(y, w - 1))] = 1;
  }
  bool any = false;
  cv::Mat picture(h, w, CV_8U);
  for (int y = 0; y < h; ++y) {
    const int* l = labels.ptr<int>(y);
    const uint8_t* b = black.ptr<uint8_t>(y);
    uint8_t* m = picture.ptr<uint8_t>(y);
    for (int x = 0; x < w; ++x) {
      const bool none = b[x] && outer[size_t(l[x])];
      m[x] = none ? 0 : 255;
      any = any || none;
    }
  }
  if (!any) return {};
  cv::Mat distance;
  cv::distanceTransform(picture, distance, cv::DIST_L2, cv::DIST_MASK_PRECISE);
  return distance;
}

class PhotoPyramid {
 public:
  // Takes the photo's pixels (RGB: without a copy).
  explicit PhotoPyramid(Image&& photo) {
    Level base{photo.width, photo.height, {}};
    if (photo.channels == 3) {
      base.rgb = std::move(photo.pixels);
    } else {
      base.rgb.resize(photo.pixelCount() * 3);
      for (size_t i = 0; i < photo.pixelCount(); ++i) {
        const float* s = photo.pixels.data() + i * size_t(photo.channels);
        float* d = base.rgb.data() + i * 3;
        if (photo.channels >= 3) {
          d[0] = s[0], d[1] = s[1], d[2] = s[2];
        } else {
          d[0] = d[1] = d[2] = s[0];
        }
      }
    }
    photo = Image();
    levels_.push_back(std::move(base));
    while (levels_.back().width > 1 || levels_.back().height > 1) {
      const Level& c = levels_.back();
      Level p{std::max(1, (c.width + 1) / 2), std::max(1, (c.height + 1) / 2), {}};
      p.rgb.assign(size_t(p.width) * size_t(p.height) * 3, 0.0f);
      parallelFor(0, p.height, [&](int64_t yy) {
        const int y = int(yy);
        const int y0 = std::min(2 * y, c.height - 1), y1 = std::min(2 * y + 1, c.height - 1);
        for (int x = 0; x < p.width; ++x) {
          const int x0 = std::min(2 * x, c.width - 1), x1 = std::min(2 * x + 1, c.width - 1);
          float* d = p.rgb.data() + (size_t(y) * size_t(p.width) + size_t(x)) * 3;
          for (int k = 0; k < 3; ++k)
            d[k] = 0.25f * (c.at(x0, y0)[k] + c.at(x1, y0)[k] + c.at(x0, y1)[k] + c.at(x1, y1)[k]);
        }
      });
      levels_.push_back(std::move(p));
    }
  }

  // Trilinear lookup at continuous level-0 pixel coordinates (origin at the top-left corner).
  glm::vec3 sample(double px, double py, float level) const {
    level = std::clamp(level, 0.0f, float(levels_.size() - 1));
    const int l0 = int(level);
    const float t = level - float(l0);
    const glm::vec3 a = bilinear(levels_[size_t(l0)], px, py, l0);
    if (t <= 0.0f || l0 + 1 >= int(levels_.size())) return a;
    return a + t * (bilinear(levels_[size_t(l0) + 1], px, py, l0 + 1) - a);
  }

 private:
  struct Level {
    int width, height;
    Pixels rgb;
    const float* at(int x, int y) const {
      return rgb.data() + (size_t(y) * size_t(width) + size_t(x)) * 3;
    }
  };
  static glm::vec3 bilinear(const Level& L, double px, double py, int level) {
    const double scale = std::ldexp(1.0, -level);
    const double u = px * scale - 0.5, v = py * scale - 0.5;
    const double fu = std::floor(u), fv = std::floor(v);
    const int x0 = std::clamp(int(fu), 0, L.width - 1), y0 = std::clamp(int(fv), 0, L.height - 1);
    const int x1 = std::clamp(int(fu) + 1, 0, L.width - 1),
              y1 = std::clamp(int(fv) + 1, 0, L.height - 1);
    const float fx = float(u - fu), fy = float(v - fv);
    const float* a = L.at(x0, y0);
    const float* b = L.at(x1, y0);
    const float* c = L.at(x0, y1);
    const float* d = L.at(x1, y1);
    glm::vec3 out;
    for (int k = 0; k < 3; ++k)
      out[k] = (a[k] * (1 - fx) + b[k] * fx) * (1 - fy) + (c[k] * (1 - fx) + d[k] * fx) * fy;
    return out;
  }
  std::vector<Level> levels_;
};

float luminance(const float* p, int channels) {
  return channels >= 3 ? 0.2126f * p[0] + 0.7152f * p[1] + 0.0722f * p[2] : p[0];
}

struct Features {
  double scale = 1.0;              // photo pixels per feature-image pixel
  cv::Mat luminance;               // CV_32F, feature image size
  std::vector<cv::KeyPoint> keys;  // in the feature image
  std::vector<glm::dvec3> rays;    // unit rays in the camera frame (0 if the lens has none)
  std::vector<float> radiance;     // luminance around each keypoint
  cv::Mat descriptors;
};

// The half angle of the cone around the optical axis that holds the whole frame.
double frustumHalfAngle(const calib::Lens& lens) {
  double worst = 0.0;
  for (double y : {0.0, 0.5, 1.0}) {
    for (double x : {0.0, 0.5, 1.0}) {
      glm::dvec3 r;
      if (lens.direction(x * lens.width, y * lens.height, r))
        worst = std::max(worst, angleBetween(r, glm::dvec3(0, 0, -1)));
      else
        worst = kPi;
    }
  }
  return worst;
}

struct PairMatches {
  int i = 0, j = 0;
  std::vector<std::pair<int, int>> inliers;  // keypoint indices in i and j
  glm::dmat3 relative{1.0};                  // cam i → cam j
  double rejected = 0.0;  // > 0: matched, but the overlap's light said no (this cost ratio)
  // Keypoints of each photo that the rough orientations put inside the other's frame (no margin),
  // the fewer of the two: how much detail the pair shares as roughly placed.
  size_t sharedKeypoints = 0;
};

// How well photo j, turned by `jFromI` relative to photo i, agrees with i where they overlap: the
// variance of log(L_i / L_j) over a grid of i's feature image, per sample, with `li` and `lj`
// their feature images' luminance blurred by 1.5 pixels; the mean is the exposure offset. -1 when
// fewer than 100 samples overlap.
double overlapLogVariance(int i, int j, const glm::dmat3& jFromI, const cv::Mat& li,
                          const cv::Mat& lj, const std::vector<StitchPhoto>& photos,
                          const std::vector<Features>& features) {
  const Features& fi = features[size_t(i)];
  const Features& fj = features[size_t(j)];
  double sum = 0.0, sum2 = 0.0;
  size_t count = 0;
  for (int y = 2; y < li.rows - 2; y += 3) {
    for (int x = 2; x < li.cols - 2; x += 3) {
      const float a = li.at<float>(y, x);
      glm::dvec3 ray;
      if (!(a > 0.0f) ||
          !photos[size_t(i)].lens.direction((x + 0.5) * fi.scale, (y + 0.5) * fi.scale, ray))
        continue;
      glm::dvec2 p;
      if (!photos[size_t(j)].lens.project(jFromI * ray, p)) continue;
      const double u = p.x / fj.scale - 0.5, v = p.y / fj.scale - 0.5;
      if (!(u >= 0.0 && v >= 0.0 && u < lj.cols - 1 && v < lj.rows - 1)) continue;
      const int x0 = int(u), y0 = int(v);
      const float tx = float(u - x0), ty = float(v - y0);
      const float b =
          (lj.at<float>(y0, x0) * (1 - tx) + lj.at<float>(y0, x0 + 1) * tx) * (1 - ty) +
          (lj.at<float>(y0 + 1, x0) * (1 - tx) + lj.at<float>(y0 + 1, x0 + 1) * tx) * ty;
      if (!(b > 0.0f)) continue;
      const double r = std::log(double(a) / double(b));
      sum += r;
      sum2 += r * r;
      ++count;
    }
  }
  if (count < 100) return -1.0;
  return (sum2 - sum * sum / double(count)) / double(count);
}

// Putative matches between photos i and j, then RANSAC on their relative rotation.
PairMatches matchPair(int i, int j, const std::vector<StitchPhoto>& photos,
                      const std::vector<Features>& features, const StitchOptions& options) {
  PairMatches out;
  out.i = i;
  out.j = j;
  const Features& fi = features[size_t(i)];
  const Features& fj = features[size_t(j)];
  const glm::dmat3 roughIj =
      glm::transpose(photos[size_t(j)].worldFromCamera) * photos[size_t(i)].worldFromCamera;
  const double tolerance = 2.0 * options.maxCorrectionDegrees * kDegrees + 2.0 * kDegrees;
  // Keypoints of one photo that the rough orientations could put inside the other's frame.
  auto candidates = [&](const Features& f, const glm::dmat3& toOther, const calib::Lens& other,
                        size_t& inside) {
    std::vector<int> keep;
    const double margin = std::tan(tolerance) * other.fx;
    inside = 0;
    for (size_t k = 0; k < f.rays.size(); ++k) {
      if (f.rays[k] == glm::dvec3(0.0)) continue;
      glm::dvec2 p;
      if (!other.project(toOther * f.rays[k], p)) continue;
      if (p.x > -margin && p.x < other.width + margin && p.y > -margin &&
          p.y < other.height + margin)
        keep.push_back(int(k));
      if (p.x >= 0.0 && p.x < other.width && p.y >= 0.0 && p.y < other.height) ++inside;
    }
    return keep;
  };
  size_t insideJ = 0, insideI = 0;
  const std::vector<int> ki = candidates(fi, roughIj, photos[size_t(j)].lens, insideJ);
  const std::vector<int> kj =
      candidates(fj, glm::transpose(roughIj), photos[size_t(i)].lens, insideI);
  out.sharedKeypoints = std::min(insideI, insideJ);
  if (ki.size() < 8 || kj.size() < 8) return out;
  cv::Mat di(int(ki.size()), fi.descriptors.cols, fi.descriptors.type());
  cv::Mat dj(int(kj.size()), fj.descriptors.cols, fj.descriptors.type());
  for (size_t k = 0; k < ki.size(); ++k) fi.descriptors.row(ki[k]).copyTo(di.row(int(k)));
  for (size_t k = 0; k < kj.size(); ++k) fj.descriptors.row(kj[k]).copyTo(dj.row(int(k)));
  cv::BFMatcher matcher(cv::NORM_L2);
  std::vector<std::vector<cv::DMatch>> knn;
  matcher.knnMatch(di, dj, knn, 2);
  std::vector<std::pair<int, int>> putative;
  for (const auto& m : knn) {
    if (m.size() < 2 || !(m[0].distance < 0.8f * m[1].distance)) continue;
    const int a = ki[size_t(m[0].queryIdx)], b = kj[size_t(m[0].trainIdx)];
    if (angleBetween(roughIj * fi.rays[size_t(a)], fj.rays[size_t(b)]) < tolerance)
      putative.push_back({a, b});
  }
  if (putative.size() < 8) return out;

  // RANSAC: two rays fix the rotation; inliers within ~2 feature pixels.
  const double threshold =
      2.0 * fi.scale / std::min(photos[size_t(i)].lens.fx, photos[size_t(j)].lens.fx) + 1e-4;
  std::mt19937 rng(uint32_t(1000 * i + j));
  std::uniform_int_distribution<size_t> pick(0, putative.size() - 1);
  std::vector<size_t> best;
  for (int it = 0; it < 300; ++it) {
    const size_t p = pick(rng), q = pick(rng);
    if (p == q) continue;
    const glm::dvec3 a1 = fi.rays[size_t(putative[p].first)],
                     a2 = fi.rays[size_t(putative[q].first)];
    const glm::dvec3 b1 = fj.rays[size_t(putative[p].second)],
                     b2 = fj.rays[size_t(putative[q].second)];
    if (angleBetween(a1, a2) < 1.0 * kDegrees) continue;  // too close to fix a rotation
    const glm::dmat3 r = kabsch({a1, a2, glm::normalize(glm::cross(a1, a2))},
                                {b1, b2, glm::normalize(glm::cross(b1, b2))});
    if (rotationAngle(r, roughIj) > tolerance) continue;
    std::vector<size_t> in;
    for (size_t k = 0; k < putative.size(); ++k) {
      if (angleBetween(r * fi.rays[size_t(putative[k].first)],
                       fj.rays[size_t(putative[k].second)]) < threshold)
        in.push_back(k);
    }
    if (in.size() > best.size()) best = std::move(in);
  }
  if (best.size() < kMinInliers) return out;
  // Refit on all inliers, then take the final inlier set.
  std::vector<glm::dvec3> a, b;
  for (size_t k : best) {
    a.push_back(fi.rays[size_t(putative[k].first)]);
    b.push_back(fj.rays[size_t(putative[k].second)]);
  }
  out.relative = kabsch(a, b);
  for (const auto& m : putative) {
    if (angleBetween(out.relative * fi.rays[size_t(m.first)], fj.rays[size_t(m.second)]) <
        threshold)
      out.inliers.push_back(m);
  }
  if (out.inliers.size() < kMinInliers) {
    out.inliers.clear();
    return out;
  }
  // The matches must explain the overlap's light better than the rough orientations do: a few
  // matches bunched in a small patch of a narrow overlap hardly fix the roll about their own
  // direction, and can agree within their threshold on a rotation degrees off.
  cv::Mat li, lj;
  cv::GaussianBlur(fi.luminance, li, cv::Size(0, 0), 1.5);
  cv::GaussianBlur(fj.luminance, lj, cv::Size(0, 0), 1.5);
  const double matched = overlapLogVariance(i, j, out.relative, li, lj, photos, features);
  const double rough = overlapLogVariance(i, j, roughIj, li, lj, photos, features);
  if (rough > 0.0 && matched < 0.0) {
    // The matched rotation turns the overlap away altogether: certainly wrong.
    out.rejected = std::numeric_limits<double>::infinity();
    out.inliers.clear();
  } else if (matched > 0.0 && rough > 0.0 && matched > kMatchedOverRough * rough) {
    out.rejected = matched / rough;
    out.inliers.clear();
  }
  return out;
}

// OpenCV's camera frame (x right, y down, looking along +z) from ours (x right, y up, -z).
const glm::dmat3 kCvFromOurs(glm::dvec3(1, 0, 0), glm::dvec3(0, -1, 0), glm::dvec3(0, 0, -1));

// Rotation-only bundle adjustment of one connected group with OpenCV's stitching module.
bool adjust(const std::vector<int>& group, const std::vector<PairMatches>& pairs,
            const std::vector<Features>& features, const std::vector<StitchPhoto>& photos,
            std::vector<glm::dmat3>& orientation, double& rms) {
  const int n = int(group.size());
  std::vector<int> local(photos.size(), -1);
  for (int k = 0; k < n; ++k) local[size_t(group[size_t(k)])] = k;
  std::vector<cv::detail::ImageFeatures> feats(static_cast<size_t>(n));
  std::vector<cv::detail::CameraParams> cameras(static_cast<size_t>(n));
  std::vector<double> focal(static_cast<size_t>(n));
  for (int k = 0; k < n; ++k) {
    const int p = group[size_t(k)];
    const Features& f = features[size_t(p)];
    // Ideal pinhole coordinates of the rays, at the feature image's scale, centred on the axis.
    focal[size_t(k)] = photos[size_t(p)].lens.fx / f.scale;
    feats[size_t(k)].img_idx = k;
    feats[size_t(k)].img_size = cv::Size(f.luminance.cols, f.luminance.rows);
    feats[size_t(k)].keypoints.resize(f.rays.size());
    for (size_t r = 0; r < f.rays.size(); ++r) {
      const glm::dvec3 c = kCvFromOurs * f.rays[r];
      cv::Point2f pt(0.0f, 0.0f);
      if (c.z > 1e-3)
        pt = cv::Point2f(float(focal[size_t(k)] * c.x / c.z), float(focal[size_t(k)] * c.y / c.z));
      feats[size_t(k)].keypoints[r].pt = pt;
    }
    cv::detail::CameraParams& cam = cameras[size_t(k)];
    cam.focal = focal[size_t(k)];
    cam.ppx = cam.ppy = 0.0;
    cam.aspect = 1.0;
    const glm::dmat3 r = orientation[size_t(p)] * kCvFromOurs;  // world from OpenCV camera
    cv::Mat R(3, 3, CV_32F);
    for (int a = 0; a < 3; ++a)
      for (int b = 0; b < 3; ++b) R.at<float>(a, b) = float(r[b][a]);
    cam.R = R;
  }
  std::vector<cv::detail::MatchesInfo> matches(size_t(n) * size_t(n));
  int total = 0;
  for (const PairMatches& pm : pairs) {
    if (pm.inliers.empty() || local[size_t(pm.i)] < 0 || local[size_t(pm.j)] < 0) continue;
    int a = local[size_t(pm.i)], b = local[size_t(pm.j)];
    bool swap = a > b;
    if (swap) std::swap(a, b);
    cv::detail::MatchesInfo& m = matches[size_t(a) * size_t(n) + size_t(b)];
    m.src_img_idx = a;
    m.dst_img_idx = b;
    for (const auto& [p, q] : pm.inliers) {
      const int qa = swap ? q : p, qb = swap ? p : q;
      // Rays too oblique for a pinhole (beyond 75° off the axis) stay out of the adjustment.
      const glm::dvec3 ra = features[size_t(group[size_t(a)])].rays[size_t(qa)];
      const glm::dvec3 rb = features[size_t(group[size_t(b)])].rays[size_t(qb)];
      if (-ra.z < std::cos(75.0 * kDegrees) || -rb.z < std::cos(75.0 * kDegrees)) continue;
      m.matches.emplace_back(qa, qb, 0.0f);
    }
    m.inliers_mask.assign(m.matches.size(), 1);
    m.num_inliers = int(m.matches.size());
    m.confidence = m.num_inliers >= int(kMinInliers) ? 1.0 : 0.0;
    m.H = cv::Mat::eye(3, 3, CV_64F);
    total += m.num_inliers;
  }
  if (total == 0) return false;
  cv::detail::BundleAdjusterReproj adjuster;
  adjuster.setConfThresh(0.5);
  adjuster.setRefinementMask(cv::Mat::zeros(3, 3, CV_8U));  // intrinsics are known: rotations only
  if (!adjuster(feats, matches, cameras)) return false;
  // Residual, and the refined rotations back in our frame.
  std::vector<glm::dmat3> refined(static_cast<size_t>(n));
  for (int k = 0; k < n; ++k) {
    glm::dmat3 r;
    for (int a = 0; a < 3; ++a)
      for (int b = 0; b < 3; ++b) r[b][a] = double(cameras[size_t(k)].R.at<float>(a, b));
    refined[size_t(k)] = nearestRotation(r * kCvFromOurs);
  }
  double sum = 0.0;
  int count = 0;
  for (int a = 0; a < n; ++a) {
    for (int b = a + 1; b < n; ++b) {
      const auto& m = matches[size_t(a) * size_t(n) + size_t(b)];
      for (const auto& d : m.matches) {
        const glm::dvec3 ra =
            refined[size_t(a)] * features[size_t(group[size_t(a)])].rays[size_t(d.queryIdx)];
        const glm::dvec3 rb =
            refined[size_t(b)] * features[size_t(group[size_t(b)])].rays[size_t(d.trainIdx)];
        const double e = angleBetween(ra, rb) * focal[size_t(a)];
        sum += e * e;
        ++count;
      }
    }
  }
  rms = count ? std::sqrt(sum / count) : 0.0;
  // The adjustment fixes its gauge on one camera; put the group back where the rough
  // orientations say it is, as a whole.
  std::vector<glm::dmat3> rough;
  for (int k = 0; k < n; ++k) rough.push_back(orientation[size_t(group[size_t(k)])]);
  const glm::dmat3 g = towardsRough(rough, refined);
  for (int k = 0; k < n; ++k) orientation[size_t(group[size_t(k)])] = g * refined[size_t(k)];
  return true;
}

// Direct alignment of a photo that shares no features with its neighbours (a clear sky, a blank
// wall): its orientation is adjusted so that the log luminance it sees in the overlaps agrees with
// what its already aligned neighbours see there, up to one exposure offset per neighbour. The
// search is a pattern search over small rotations about the camera's axes, from 1° down to 0.005°.
// Returns the rotation and, per neighbour, the mean log ratio log(L_i / L_j) over the overlap.
struct Photometric {
  bool ok = false;
  glm::dmat3 worldFromCamera{1.0};
  double cost = 0.0, initialCost = 0.0;
  std::vector<std::pair<int, double>> logRatios;  // (neighbour, log(L_i / L_j))
};

Photometric alignPhotometric(int i, const std::vector<int>& neighbours,
                             const std::vector<StitchPhoto>& photos,
                             const std::vector<Features>& features,
                             const std::vector<glm::dmat3>& orientation, double maxCorrection) {
  Photometric out;
  auto blurred = [&](int k) {
    cv::Mat b;
    cv::GaussianBlur(features[size_t(k)].luminance, b, cv::Size(0, 0), 1.5);
    return b;
  };
  auto sampleAt = [](const cv::Mat& lum, double fx, double fy) {
    const double u = fx - 0.5, v = fy - 0.5;
    // Range-checked in double first: a ray far outside the photo (or NaN) has no int pixel.
    if (!(u >= 0.0 && v >= 0.0 && u < lum.cols - 1 && v < lum.rows - 1)) return -1.0f;
    const int x0 = int(std::floor(u)), y0 = int(std::floor(v));
    const float tx = float(u - x0), ty = float(v - y0);
    const float a = lum.at<float>(y0, x0), b = lum.at<float>(y0, x0 + 1);
    const float c = lum.at<float>(y0 + 1, x0), d = lum.at<float>(y0 + 1, x0 + 1);
    return (a * (1 - tx) + b * tx) * (1 - ty) + (c * (1 - tx) + d * tx) * ty;
  };
  const Features& fi = features[size_t(i)];
  const calib::Lens& lens = photos[size_t(i)].lens;
  const cv::Mat li = blurred(i);
  // Samples: rays on a grid of the photo, with their log luminance.
  struct Sample {
    glm::dvec3 ray;
    double logL;
  };
  std::vector<Sample> samples;
  for (int y = 2; y < li.rows - 2; y += 3) {
    for (int x = 2; x < li.cols - 2; x += 3) {
      const float L = li.at<float>(y, x);
      glm::dvec3 r;
      if (L > 0.0f && lens.direction((x + 0.5) * fi.scale, (y + 0.5) * fi.scale, r))
        samples.push_back({r, std::log(double(L))});
    }
  }
  struct Neighbour {
    int j;
    cv::Mat lum;
  };
  std::vector<Neighbour> others;
  for (int j : neighbours) others.push_back({j, blurred(j)});
  // Cost of an orientation: the variance of log(L_i) - log(L_j) over the overlap, per neighbour
  // (the mean is the exposure offset), summed; also the sample count and the means.
  size_t initialCount = 0;
  auto evaluate = [&](const glm::dmat3& worldFromI, size_t& used,
                      std::vector<std::pair<int, double>>* means) {
    double cost = 0.0;
    used = 0;
    for (const Neighbour& nb : others) {
      const glm::dmat3 jFromI = glm::transpose(orientation[size_t(nb.j)]) * worldFromI;
      const Features& fj = features[size_t(nb.j)];
      const calib::Lens& lj = photos[size_t(nb.j)].lens;
      double sum = 0.0, sum2 = 0.0;
      size_t count = 0;
      for (const Sample& smp : samples) {
        glm::dvec2 p;
        if (!lj.project(jFromI * smp.ray, p)) continue;
        const float L = sampleAt(nb.lum, p.x / fj.scale, p.y / fj.scale);
        if (!(L > 0.0f)) continue;
        const double r = smp.logL - std::log(double(L));
        sum += r;
        sum2 += r * r;
        ++count;
      }
      if (count < 20) continue;
      cost += sum2 - sum * sum / double(count);
      used += count;
      if (means) means->push_back({nb.j, sum / double(count)});
    }
    return cost;
  };
  glm::dmat3 best = orientation[size_t(i)];
  out.initialCost = evaluate(best, initialCount, nullptr);
  if (initialCount < 100) return out;
  auto rotate = [&](const glm::dmat3& r, int axis, double radians) {
    glm::dvec3 e(0.0);
    e[axis] = 1.0;
    cv::Mat rv = (cv::Mat_<double>(3, 1) << e.x * radians, e.y * radians, e.z * radians);
    cv::Mat m;
    cv::Rodrigues(rv, m);
    glm::dmat3 g;
    for (int a = 0; a < 3; ++a)
      for (int b = 0; b < 3; ++b) g[b][a] = m.at<double>(a, b);
    return r * g;  // about the camera's own axes
  };
  // Costs are compared per sample, so that samples leaving the overlap do not look like progress.
  size_t used = initialCount;
  double cost = out.initialCost / double(initialCount);
  for (double step = 1.0 * kDegrees; step > 0.005 * kDegrees;) {
    bool improved = false;
    for (int axis = 0; axis < 3 && !improved; ++axis) {
      for (double sign : {1.0, -1.0}) {
        const glm::dmat3 trial = rotate(best, axis, sign * step);
        if (rotationAngle(trial, orientation[size_t(i)]) > maxCorrection) continue;
        size_t n = 0;
        const double c = evaluate(trial, n, nullptr);
        if (n < initialCount / 2) continue;
        if (c / double(n) < cost * (1.0 - 1e-4)) {
          best = trial;
          cost = c / double(n);
          used = n;
          improved = true;
          break;
        }
      }
    }
    if (!improved) step *= 0.5;
  }
  (void)used;
  out.cost = cost;
  out.initialCost /= double(initialCount);
  out.worldFromCamera = best;
  size_t n = 0;
  evaluate(best, n, &out.logRatios);
  out.ok = true;
  return out;
}

// Accumulates wall-clock time per named step.
class StepTimer {
 public:
  explicit StepTimer(std::vector<std::pair<std::string, double>>& out) : out_(out) {}
  void add(const std::string& step, std::chrono::steady_clock::time_point since) {
    const double s =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - since).count();
    for (auto& [name, total] : out_) {
      if (name == step) {
        total += s;
        return;
      }
    }
    out_.push_back({step, s});
  }

 private:
  std::vector<std::pair<std::string, double>>& out_;
};

std::string fmt(const char* format, double a, double b = 0.0, double c = 0.0) {
  char s[256];
  std::snprintf(s, sizeof s, format, a, b, c);
  return s;
}

}  // namespace

void StitchOptions::validate() const {
  if (faceSize < 8 || faceSize > 8192) throw UsageError("the cube face size must be 8..8192");
  if (!(maxCorrectionDegrees > 0.0 && maxCorrectionDegrees <= 45.0))
    throw UsageError("the orientation tolerance must be within (0, 45] degrees");
  if (featureSize < 200 || featureSize > 8000)
    throw UsageError("the feature image size must be 200..8000 pixels");
}

StitchResult stitch(const std::vector<StitchPhoto>& photos, const std::function<Image(int)>& load,
                    const StitchOptions& options, const Progress& progress) {
  options.validate();
  const int count = int(photos.size());
  if (count < 1) throw Error("stitch", "no photos to stitch");
  for (const StitchPhoto& p : photos) p.lens.validate(p.name);
  StitchResult result;
  result.worldFromCamera.resize(size_t(count));
  for (int i = 0; i < count; ++i)
    result.worldFromCamera[size_t(i)] = photos[size_t(i)].worldFromCamera;
  result.gains.assign(size_t(count), 1.0f);
  result.correctionDegrees.assign(size_t(count), 0.0);

  std::vector<Image> kept(static_cast<size_t>(count));
  auto loadChecked = [&](int i) {
    Image img = load(i);
    const StitchPhoto& p = photos[size_t(i)];
    if (img.width != p.lens.width || img.height != p.lens.height) {
      throw Error("stitch",
                  "the photo is " + std::to_string(img.width) + "x" + std::to_string(img.height) +
                      " but its lens is for " + std::to_string(p.lens.width) + "x" +
                      std::to_string(p.lens.height),
                  p.name);
    }
    if (img.channels < 1) throw Error("stitch", "the photo has no channels", p.name);
    return img;
  };

  StepTimer timer(result.seconds);
  using Clock = std::chrono::steady_clock;

  // 1. Features (and, if kept, the photos themselves).
  std::vector<Features> features(static_cast<size_t>(count));
  const bool refine = options.refine && count > 1;
  // Loading and the feature images, photo by photo: in parallel when the photos are kept anyway,
  // one at a time otherwise.
  auto prepare = [&](int i) {
    Image img = loadChecked(i);
    if (refine) {
      Features& f = features[size_t(i)];
      const int longSide = std::max(img.width, img.height);
      f.scale = std::max(1.0, double(longSide) / options.featureSize);
      cv::Mat lum(img.height, img.width, CV_32F);
      for (int y = 0; y < img.height; ++y) {
        float* row = lum.ptr<float>(y);
        for (int x = 0; x < img.width; ++x) row[x] = luminance(img.at(x, y), img.channels);
      }
      if (f.scale > 1.0) {
        cv::resize(lum, f.luminance,
                   cv::Size(std::max(1, int(std::lround(img.width / f.scale))),
                            std::max(1, int(std::lround(img.height / f.scale)))),
                   0, 0, cv::INTER_AREA);
        f.scale = double(img.width) / f.luminance.cols;
      } else {
        f.luminance = lum;
      }
    }
    if (options.keepPhotos) kept[size_t(i)] = std::move(img);
  };
  if (refine || options.keepPhotos) {
    const auto t0 = Clock::now();
    ParallelProgress loaded(progress, "load", count, 1);
    if (options.keepPhotos) {
      parallelFor(0, count, [&](int64_t i) {
        prepare(int(i));
        loaded.step();
      });
    } else {
      for (int i = 0; i < count; ++i) {
        prepare(i);
        loaded.step();
      }
    }
    timer.add("load", t0);
  }

  if (refine) {
    auto t0 = Clock::now();
    // One log-luminance tone mapping for every photo, so that features repeat across photos.
    std::vector<float> logs;
    for (const Features& f : features) {
      const int step = std::max(1, int(f.luminance.total() / 20000));
      for (size_t k = 0; k < f.luminance.total(); k += size_t(step)) {
        const float v = f.luminance.ptr<float>()[k];
        if (v > 0.0f) logs.push_back(std::log2(v));
      }
    }
    float lo = -10.0f, hi = 10.0f;
    if (logs.size() > 100) {
      std::sort(logs.begin(), logs.end());
      lo = logs[logs.size() / 200];
      hi = logs[logs.size() - 1 - logs.size() / 500];
      if (!(hi > lo + 1e-3f)) hi = lo + 1.0f;
    }
    parallelFor(0, count, [&](int64_t i) {
      Features& f = features[size_t(i)];
      const StitchPhoto& p = photos[size_t(i)];
      cv::Mat grey(f.luminance.size(), CV_8U);
      for (int y = 0; y < grey.rows; ++y) {
        const float* s = f.luminance.ptr<float>(y);
        uint8_t* d = grey.ptr<uint8_t>(y);
        for (int x = 0; x < grey.cols; ++x) {
          const float v = s[x] > 0.0f ? (std::log2(s[x]) - lo) / (hi - lo) : 0.0f;
          d[x] = uint8_t(std::clamp(v, 0.0f, 1.0f) * 255.0f + 0.5f);
        }
      }
      // Local contrast equalisation brings out texture in skies and shadows.
      cv::createCLAHE(3.0, cv::Size(8, 8))->apply(grey, grey);
      cv::Ptr<cv::SIFT> sift = cv::SIFT::create(4000, 3, 0.015);
      sift->detectAndCompute(grey, cv::noArray(), f.keys, f.descriptors);
      f.rays.resize(f.keys.size());
      f.radiance.resize(f.keys.size());
      for (size_t k = 0; k < f.keys.size(); ++k) {
        const cv::Point2f& pt = f.keys[k].pt;  // OpenCV: pixel centres at integers
        glm::dvec3 ray;
        if (p.lens.direction((pt.x + 0.5) * f.scale, (pt.y + 0.5) * f.scale, ray)) f.rays[k] = ray;
        // Radiance around the keypoint: mean over 3 x 3 feature pixels.
        const int cx = std::clamp(int(pt.x + 0.5f), 1, std::max(1, f.luminance.cols - 2));
        const int cy = std::clamp(int(pt.y + 0.5f), 1, std::max(1, f.luminance.rows - 2));
        float sum = 0.0f;
        int n = 0;
        for (int y = cy - 1; y <= cy + 1; ++y)
          for (int x = cx - 1; x <= cx + 1; ++x)
            if (x >= 0 && y >= 0 && x < f.luminance.cols && y < f.luminance.rows) {
              sum += f.luminance.at<float>(y, x);
              ++n;
            }
        f.radiance[k] = n ? sum / float(n) : 0.0f;
      }
    });
    report(progress, "features", 1.0);

    timer.add("features", t0);
    t0 = Clock::now();
    // 2. Matching, pairs whose rough frusta can overlap.
    std::vector<std::pair<int, int>> candidates;
    for (int i = 0; i < count; ++i) {
      for (int j = i + 1; j < count; ++j) {
        const double axes = angleBetween(photos[size_t(i)].worldFromCamera * glm::dvec3(0, 0, -1),
                                         photos[size_t(j)].worldFromCamera * glm::dvec3(0, 0, -1));
        if (axes < frustumHalfAngle(photos[size_t(i)].lens) +
                       frustumHalfAngle(photos[size_t(j)].lens) +
                       2.0 * options.maxCorrectionDegrees * kDegrees)
          candidates.push_back({i, j});
      }
    }
    std::vector<PairMatches> pairs(candidates.size());
    parallelFor(0, int64_t(candidates.size()), [&](int64_t k) {
      pairs[size_t(k)] = matchPair(candidates[size_t(k)].first, candidates[size_t(k)].second,
                                   photos, features, options);
    });
    report(progress, "match", 0.5);
    int verified = 0;
    for (const PairMatches& pm : pairs) {
      if (!pm.inliers.empty()) ++verified;
      if (pm.rejected > 0.0)
        result.notes.push_back(
            "photos " + photos[size_t(pm.i)].name + " and " + photos[size_t(pm.j)].name +
            (std::isinf(pm.rejected) ? std::string(": their matches turn them apart so that they "
                                                   "no longer overlap; not used")
                                     : fmt(": their matches turn them so that the light of their "
                                           "overlap agrees %.1f times worse than as roughly "
                                           "placed; not used",
                                           pm.rejected)));
    }
    result.notes.push_back(std::to_string(verified) + " of " + std::to_string(candidates.size()) +
                           " overlapping photo pairs matched");
    // Photos that, as roughly placed, put many keypoints inside each other's frames share that
    // detail; when hardly any such pair matches, the photos are most likely not where their
    // names (or their order) put them. (Photos that only touch, as 90° cube faces do, share none.)
    constexpr size_t kShared = 50;
    int detailedPairs = 0, detailedMatched = 0;
    for (const PairMatches& pm : pairs) {
      if (pm.sharedKeypoints < kShared) continue;
      ++detailedPairs;
      if (!pm.inliers.empty()) ++detailedMatched;
    }
    if (detailedPairs >= 2 && 4 * detailedMatched < detailedPairs) {
      result.warnings.push_back(
          std::to_string(detailedMatched) + " of " + std::to_string(detailedPairs) +
          " overlapping pairs of photos with detail matched by their features: are the photos' "
          "directions right? (their names _px _nx ..., @YAW,PITCH, or, for six unnamed photos, "
          "the order +X -X +Y -Y +Z -Z)");
    }

    timer.add("match", t0);
    t0 = Clock::now();
    // 3. Orientation: bundle adjustment per connected group.
    std::vector<int> component(static_cast<size_t>(count));
    std::iota(component.begin(), component.end(), 0);
    std::function<int(int)> find = [&](int a) {
      return component[size_t(a)] == a ? a : component[size_t(a)] = find(component[size_t(a)]);
    };
    for (const PairMatches& pm : pairs) {
      if (!pm.inliers.empty()) component[size_t(find(pm.i))] = find(pm.j);
    }
    std::vector<glm::dmat3> orientation = result.worldFromCamera;
    for (int root = 0; root < count; ++root) {
      std::vector<int> group;
      for (int i = 0; i < count; ++i)
        if (find(i) == root) group.push_back(i);
      if (group.size() < 2) {
        if (group.size() == 1)
          result.notes.push_back("photo " + photos[size_t(group[0])].name +
                                 " matched no other photo by its features");
        continue;
      }
      std::vector<glm::dmat3> trial = orientation;
      double rms = 0.0;
      if (!adjust(group, pairs, features, photos, trial, rms)) {
        result.notes.push_back("the bundle adjustment failed; rough orientations are kept");
        continue;
      }
      double worst = 0.0;
      for (int i : group)
        worst = std::max(worst, rotationAngle(trial[size_t(i)], orientation[size_t(i)]));
      if (worst > options.maxCorrectionDegrees * kDegrees) {
        result.notes.push_back(
            fmt("the refined orientations differ from the rough ones by up to "
                "%.1f degrees, more than the tolerance of %.1f: rough "
                "orientations are kept",
                worst / kDegrees, options.maxCorrectionDegrees));
        continue;
      }
      for (int i : group) orientation[size_t(i)] = trial[size_t(i)];
      result.notes.push_back(
          fmt("orientations refined for %.0f photos; reprojection error %.2f "
              "pixels (rms, feature images)",
              double(group.size()), rms));
    }
    // Photos that share no features with any other are aligned directly on the radiance of their
    // overlaps with the aligned ones.
    std::vector<bool> aligned(size_t(count), false);
    for (int i = 0; i < count; ++i) {
      for (int j = 0; j < count; ++j)
        if (j != i && find(j) == find(i)) aligned[size_t(i)] = true;
    }
    std::vector<std::pair<std::pair<int, int>, double>> photometricRatios;
    std::vector<int> photometricGroup(size_t(count), -1);  // the group a photo was aligned to
    for (int i = 0; i < count; ++i) {
      if (aligned[size_t(i)]) continue;
      std::vector<int> neighbours;
      for (const auto& [a, b] : candidates) {
        const int other = a == i ? b : b == i ? a : -1;
        if (other >= 0 && aligned[size_t(other)]) neighbours.push_back(other);
      }
      const Photometric pm = neighbours.empty()
                                 ? Photometric{}
                                 : alignPhotometric(i, neighbours, photos, features, orientation,
                                                    options.maxCorrectionDegrees * kDegrees);
      if (!pm.ok) {
        result.notes.push_back("photo " + photos[size_t(i)].name +
                               (neighbours.empty()
                                    ? " overlaps no aligned photo"
                                    : " could not be aligned on the radiance of its overlaps") +
                               ": its rough orientation is kept");
        continue;
      }
      orientation[size_t(i)] = pm.worldFromCamera;
      for (const auto& [j, logRatio] : pm.logRatios)
        photometricRatios.push_back({{i, j}, logRatio});
      photometricGroup[size_t(i)] = find(neighbours.front());
      const double turned = rotationAngle(pm.worldFromCamera, photos[size_t(i)].worldFromCamera);
      result.notes.push_back("photo " + photos[size_t(i)].name +
                             " shares no features with its neighbours: aligned on the radiance of "
                             "its overlaps instead" +
                             fmt(" (log-luminance residual %.3f from %.3f), turned by %.2f degrees",
                                 std::sqrt(pm.cost), std::sqrt(pm.initialCost), turned / kDegrees));
      // A photo put where it belongs agrees with its neighbours to a tenth or so in log-luminance
      // (noise, JPEG, gains); one whose name or suffix puts it elsewhere agrees no better after the
      // search, which then ends at its limit (two photos of a ring swapped: residual 1.05 and a
      // 9.8 degree turn against 0.08 for the others).
      const bool atLimit = turned >= 0.95 * options.maxCorrectionDegrees * kDegrees;
      if (std::sqrt(pm.cost) > 0.5 || atLimit) {
        result.warnings.push_back(
            "photo " + photos[size_t(i)].name +
            fmt(" agrees poorly with its neighbours (log-luminance residual %.2f",
                std::sqrt(pm.cost)) +
            (atLimit ? ", after turning it as far as the search goes" : "") +
            "): is its direction right? (its name _px _nx ..., @YAW,PITCH[,ROLL], or its place in "
            "the order +X -X +Y -Y +Z -Z)");
      }
    }
    // A group was put where its own photos' rough orientations say it is; the photos aligned to
    // it on radiance hold rough orientations too, and as a whole their errors are as likely as
    // the group's. Put the group and the photos aligned to it where all their rough orientations
    // say, so that leaving a photo out of the feature matching does not turn the map.
    for (int root = 0; root < count; ++root) {
      std::vector<int> members;
      bool joined = false;
      for (int i = 0; i < count; ++i) {
        if (photometricGroup[size_t(i)] >= 0 && find(photometricGroup[size_t(i)]) == root) {
          members.push_back(i);
          joined = true;
        } else if (aligned[size_t(i)] && find(i) == root) {
          members.push_back(i);
        }
      }
      if (!joined) continue;
      std::vector<glm::dmat3> rough, refined;
      for (int i : members) {
        rough.push_back(photos[size_t(i)].worldFromCamera);
        refined.push_back(orientation[size_t(i)]);
      }
      const glm::dmat3 g = towardsRough(rough, refined);
      for (int i : members) orientation[size_t(i)] = g * orientation[size_t(i)];
      result.notes.push_back(
          fmt("%.0f photos, those aligned on radiance included, put where their "
              "rough orientations say on average: turned by %.2f degrees",
              double(members.size()), rotationAngle(g, glm::dmat3(1.0)) / kDegrees));
    }
    for (int i = 0; i < count; ++i) {
      result.correctionDegrees[size_t(i)] =
          rotationAngle(orientation[size_t(i)], photos[size_t(i)].worldFromCamera) / kDegrees;
    }
    result.worldFromCamera = orientation;

    // 4. Exposure gains from the radiance at matched keypoints.
    if (options.gains) {
      struct Ratio {
        int i, j;
        double logRatio;  // log(L_i / L_j)
      };
      std::vector<Ratio> ratios;
      for (const PairMatches& pm : pairs) {
        if (pm.inliers.empty()) continue;
        std::vector<double> r;
        const float satI = photos[size_t(pm.i)].saturation, satJ = photos[size_t(pm.j)].saturation;
        for (const auto& [a, b] : pm.inliers) {
          const float la = features[size_t(pm.i)].radiance[size_t(a)];
          const float lb = features[size_t(pm.j)].radiance[size_t(b)];
          if (!(la > 0.0f && lb > 0.0f)) continue;
          if ((satI > 0.0f && la > 0.9f * satI) || (satJ > 0.0f && lb > 0.9f * satJ)) continue;
          r.push_back(std::log(double(la) / double(lb)));
        }
        if (r.size() < 8) continue;
        std::nth_element(r.begin(), r.begin() + ptrdiff_t(r.size() / 2), r.end());
        ratios.push_back({pm.i, pm.j, r[r.size() / 2]});
      }
      for (const auto& [ij, logRatio] : photometricRatios)
        ratios.push_back({ij.first, ij.second, logRatio});
      if (!ratios.empty()) {
        // Least squares for log gains a: a_i - a_j = -log(L_i / L_j) over matched pairs, with
        // Σ a = 0 (the overall exposure does not move) and a faint pull of every a towards 0, so
        // that a photo matched to nothing keeps a gain of 1.
        cv::Mat A = cv::Mat::zeros(int(ratios.size()) + 1 + count, count, CV_64F);
        cv::Mat b = cv::Mat::zeros(A.rows, 1, CV_64F);
        for (size_t k = 0; k < ratios.size(); ++k) {
          A.at<double>(int(k), ratios[k].i) = 1.0;
          A.at<double>(int(k), ratios[k].j) = -1.0;
          b.at<double>(int(k), 0) = -ratios[k].logRatio;
        }
        for (int i = 0; i < count; ++i) {
          A.at<double>(int(ratios.size()), i) = 1.0;
          A.at<double>(int(ratios.size()) + 1 + i, i) = 1e-3;
        }
        cv::Mat a;
        if (cv::solve(A, b, a, cv::DECOMP_SVD)) {
          double spread = 0.0;
          for (int i = 0; i < count; ++i) {
            result.gains[size_t(i)] = float(std::exp(a.at<double>(i, 0)));
            spread = std::max(spread, std::abs(a.at<double>(i, 0)));
          }
          result.notes.push_back(fmt("exposure gains between photos: up to %.1f %% (%.2f stops)",
                                     100.0 * (std::exp(spread) - 1.0), spread / std::log(2.0)));
        }
      }
    }
    timer.add("adjust", t0);
    report(progress, "match", 1.0);
  }

  // 5. Warping and blending.
  const int n = options.faceSize;
  const size_t texels = size_t(kCubeFaces) * size_t(n) * size_t(n);
  std::vector<float> sum(texels * 3, 0.0f), weight(texels, 0.0f), coverage(texels, 0.0f);
  for (int i = 0; i < count; ++i) {
    const StitchPhoto& p = photos[size_t(i)];
    auto t0 = Clock::now();
    Image img = options.keepPhotos ? std::move(kept[size_t(i)]) : loadChecked(i);
    if (!options.keepPhotos) timer.add("load", t0);
    t0 = Clock::now();
    const int w = img.width, h = img.height;
    const cv::Mat noPicture = distanceToNoPicture(img);
    const PhotoPyramid pyramid(std::move(img));
    const glm::dmat3 cameraFromWorld = glm::transpose(result.worldFromCamera[size_t(i)]);
    const float gain = result.gains[size_t(i)];
    const double margin = std::max(2.0, 0.01 * std::min(w, h));  // coverage ramp at the frame
    const double half = frustumHalfAngle(p.lens);
    const glm::dvec3 axis = result.worldFromCamera[size_t(i)] * glm::dvec3(0, 0, -1);
    parallelFor(0, int64_t(kCubeFaces) * n, [&](int64_t task) {
      const int f = int(task / n), y = int(task % n);
      const lighting::FaceFrame& frame = lighting::faceFrame(f);
      const double b = -1.0 + (2.0 * y + 1.0) / n, step = 2.0 / n;
      // A whole row outside the frustum is skipped.
      const glm::dvec3 rowStart = frame.forward - frame.right + b * frame.down;
      const glm::dvec3 rowEnd = frame.forward + frame.right + b * frame.down;
      const double rowHalf = 0.5 * angleBetween(rowStart, rowEnd);
      if (angleBetween(0.5 * (glm::normalize(rowStart) + glm::normalize(rowEnd)), axis) >
          half + rowHalf + step)
        return;
      // Texels whose centre falls this far outside the frame cannot reach into it: a texel's
      // half diagonal in photo pixels, bounded by the worst case of the lens at this face size.
      const double cull = 2.0 * std::max(p.lens.fx, p.lens.fy) * step + 2.0;
      // The camera-frame steps of a quarter texel along the face's right and down axes.
      const glm::dvec3 qa = cameraFromWorld * (0.25 * step * frame.right);
      const glm::dvec3 qb = cameraFromWorld * (0.25 * step * frame.down);
      for (int x = 0; x < n; ++x) {
        const double a = -1.0 + (2.0 * x + 1.0) / n;
        const glm::dvec3 c = cameraFromWorld * (frame.forward + a * frame.right + b * frame.down);
        if (p.lens.projection == calib::Projection::Rectilinear && !(c.z < 0.0)) continue;
        // Most texels miss the frame: one projection tells, before the texel's own rays.
        {
          glm::dvec2 centre;
          if (!p.lens.project(c, centre)) continue;
          if (!(centre.x > -cull && centre.x < w + cull && centre.y > -cull && centre.y < h + cull))
            continue;
        }
        // The texel as 2 x 2 sub-texel rays (a quarter texel off its centre each way), and more
        // (3 x 3, 4 x 4) when the texel spans many photo pixels: their mean, each prefiltered to
        // its own footprint, is close to the box average over the texel, which is what a cube
        // texel holds.
        glm::dvec2 ps[4];
        bool seen = true;
        for (int k = 0; k < 4 && seen; ++k)
          seen = p.lens.project(c + ((k & 1) ? qa : -qa) + ((k & 2) ? qb : -qb), ps[k]);
        if (!seen) continue;
        const glm::dvec2 px = 0.25 * (ps[0] + ps[1] + ps[2] + ps[3]);
        if (!(px.x > 0.0 && px.x < w && px.y > 0.0 && px.y < h)) continue;
        // Those rays are half a texel apart: the texel spans twice that many photo pixels.
        const double texelPixels =
            2.0 * std::max(glm::length(ps[1] - ps[0]), glm::length(ps[2] - ps[0]));
        const int m = std::clamp(int(std::ceil(texelPixels / kSubTexelPixels)), 2, 4);
        const float level = float(std::log2(std::max(1.0, texelPixels / m)));
        glm::vec3 L(0.0f);
        if (m == 2) {
          for (int k = 0; k < 4; ++k) L += pyramid.sample(ps[k].x, ps[k].y, level);
          L *= 0.25f;
        } else {
          int rays = 0;
          for (int sj = 0; sj < m; ++sj) {
            for (int si = 0; si < m; ++si) {
              const double sa = 4.0 * ((si + 0.5) / m - 0.5), sb = 4.0 * ((sj + 0.5) / m - 0.5);
              glm::dvec2 q;
              if (!p.lens.project(c + sa * qa + sb * qb, q)) continue;
              L += pyramid.sample(q.x, q.y, level);
              ++rays;
            }
          }
          L /= float(std::max(rays, 1));
        }
        L *= gain;
        // Feathering: 1 in the middle of the frame, 0 at its edges, and at the edge of the
        // picture where part of the frame holds none (a fisheye's image circle): there the texel
        // is left to other photos before its samples reach the black.
        const double fx = std::min(px.x, w - px.x) / (0.5 * w);
        const double fy = std::min(px.y, h - px.y) / (0.5 * h);
        float wt = float(fx * fy);
        double inside = std::numeric_limits<double>::max();
        if (!noPicture.empty()) {
          const int ix = std::clamp(int(px.x), 0, w - 1), iy = std::clamp(int(px.y), 0, h - 1);
          inside = double(noPicture.at<float>(iy, ix)) - texelPixels - 1.0;
          if (!(inside > 0.0)) continue;
          wt *= float(std::min(1.0, inside / (0.5 * std::min(w, h))));
        }
        if (p.saturation > 0.0f && std::max({L.x, L.y, L.z}) >= 0.98f * p.saturation * gain)
          wt *= 0.01f;
        const double edge = std::min({px.x, w - px.x, px.y, h - px.y, inside});
        const float cover = float(std::clamp(edge / margin, 0.0, 1.0));
        const size_t t = (size_t(f) * size_t(n) + size_t(y)) * size_t(n) + size_t(x);
        sum[3 * t] += wt * L.x;
        sum[3 * t + 1] += wt * L.y;
        sum[3 * t + 2] += wt * L.z;
        weight[t] += wt;
        coverage[t] = std::max(coverage[t], cover);
      }
    });
    timer.add("warp", t0);
    report(progress, "warp", double(i + 1) / count);
  }
  result.cube = lighting::CubeMap(n);
  for (int f = 0; f < kCubeFaces; ++f) {
    for (int y = 0; y < n; ++y) {
      for (int x = 0; x < n; ++x) {
        const size_t t = (size_t(f) * size_t(n) + size_t(y)) * size_t(n) + size_t(x);
        float* out = result.cube.texel(f, x, y);
        if (weight[t] > 0.0f) {
          for (int k = 0; k < 3; ++k) out[k] = sum[3 * t + size_t(k)] / weight[t];
        } else {
          coverage[t] = 0.0f;
        }
      }
    }
  }
  // 6. What no photo saw.
  const CoverageReport seen = measureCoverage(result.cube, coverage);
  if (seen.uncovered >= 1.0) throw Error("stitch", "no photo covers any direction of the cube");
  const auto t0 = Clock::now();
  result.coverage = fillUncovered(result.cube, coverage);
  timer.add("fill", t0);
  return result;
}

}  // namespace compose::cubemap
