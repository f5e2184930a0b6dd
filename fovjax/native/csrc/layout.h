// Every stride, code and operand order that the Python side and the native handlers share.
// `fovjax_native_layout` (library.cc) exports them; the loader compares the export with
// fovjax/native/_layout.py before registering a handler, and tests/test_native_layout.py compares
// both with the constants of the packages that own them.
#pragma once

#include <cstdint>

namespace {

// Materials: rows of ka (3), kd (3), ks (3), ke (3), kr (3), ns (1) (`whitted_operands`).
constexpr int kMaterialStride = 16;
// Lights: rows of position or direction towards the light (3), colour (3), a spot light's unit
// axis (3) and the cosines of its inner and outer half-angles (2).
constexpr int kLightStride = 11;
// Light kinds (`Lights.kind`).
constexpr int kLightPoint = 0, kLightDirectional = 1, kLightSpot = 2;
// Specular terms (`RenderConfig.specular`).
constexpr int kSpecularBlinnPhong = 0, kSpecularPhong = 1;
// Cameras: rows of position (3), rotation (3×3, row-major), tan(vfov / 2), aspect, offset (2).
constexpr int kCameraStride = 16;
// Regions of a pixel (fovjax/foveate/_sampling.py).
constexpr int kFovea = 0, kPeriphery = 1, kOutside = 2;
// Sample classes (fovjax/foveate/_sampling.py).
constexpr int8_t kMandatory = 0, kOptional = 1, kSkipped = 2;
// Sampling rules (`Foveation.rule`), and the methods' pixel masks (every sub-sample of the pixels
// whose P is 1: `foveate/_methods/_sparse.py`, `pixel_selection`).
constexpr int kRuleEither = 0, kRuleStrict = 1, kRuleThesisMeasured = 2, kRulePixelMask = 3;
// Shadow modes of a shading class (`ShadingClasses.shadows`, fovjax/render/_integrator.py).
constexpr int kShadowsAll = 0, kShadowsBrightest = 1, kShadowsNone = 2;
// The shading adjoint's fields (render/_whitted_adjoint.cc): bit i of its `moving` attribute
// asks for field i's gradient (ka, kd, ks, ke, kr, ns, the lights' colours, the ambient colour).
constexpr int kAdjointKa = 0, kAdjointKd = 1, kAdjointKs = 2, kAdjointKe = 3, kAdjointKr = 4, kAdjointNs = 5,
              kAdjointLightColor = 6, kAdjointAmbient = 7;
// A stored path's face where no ray was traced at that level (render/_whitted.cc, `PathsOut`).
constexpr int32_t kPathNotTraced = -2;
// The Whitted handlers' scene operands, in order (`FOVJAX_SCENE_PARAMS`, render/_whitted.cc).
constexpr const char* kSceneOperands =
    "bvh_host_id,bvh_vertices,bvh_faces,bvh_first_face,vertices,faces,face_material,normals,uvs,"
    "materials,texture,texels,texture_shape,lights,light_kind,ambient,environment,offset";

}  // namespace
