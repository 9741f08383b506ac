/* Per-frame decisions before skinning (Merry 2007, sections 7.2-7.3): frustum culling with the culling sphere,
 * level selection for a pixel tolerance, and the geomorph of texture coordinates. */
#include <math.h>

#include "sk_internal.h"

static int finite_floats(const float *values, size_t count, size_t *first_bad)
{
    for (size_t i = 0; i < count; ++i)
        if (!isfinite(values[i])) {
            *first_bad = i;
            return 0;
        }
    return 1;
}

sk_status sk_runtime_frustum_planes(float *planes, const float *view_projection, sk_error *error)
{
    static const char *const names[6] = {"left", "right", "bottom", "top", "near", "far"};
    if (!planes || !view_projection)
        return sk_fail(error, SK_ERROR_ARGUMENT, "planes and view_projection must not be null");
    size_t bad;
    if (!finite_floats(view_projection, 16, &bad))
        return sk_fail(error, SK_ERROR_NOT_FINITE, "view_projection[%zu] is a NaN or infinity", bad);
    const float *w = view_projection + 12;
    for (int p = 0; p < 6; ++p) {
        /* Gribb and Hartmann: inside the clip volume means w +- (row x, y or z) >= 0. */
        const float *row = view_projection + 4 * (p / 2);
        const double sign = p % 2 ? -1.0 : 1.0;
        double plane[4];
        for (int c = 0; c < 4; ++c)
            plane[c] = (double)w[c] + sign * (double)row[c];
        const double length = sqrt(plane[0] * plane[0] + plane[1] * plane[1] + plane[2] * plane[2]);
        if (!(length > 1e-30))
            return sk_fail(error, SK_ERROR_ARGUMENT, "the %s plane of view_projection has no normal", names[p]);
        for (int c = 0; c < 4; ++c)
            planes[4 * p + c] = (float)(plane[c] / length);
    }
    return sk_succeed(error);
}

sk_status sk_runtime_cull(uint8_t *visible, const float *spheres, size_t sphere_count, const float *planes,
                          size_t plane_count, sk_error *error)
{
    if (!visible || (!spheres && sphere_count) || (!planes && plane_count))
        return sk_fail(error, SK_ERROR_ARGUMENT, "visible, spheres and planes must not be null");
    size_t bad;
    if (!finite_floats(planes, 4 * plane_count, &bad))
        return sk_fail(error, SK_ERROR_NOT_FINITE, "plane %zu has a NaN or infinity", bad / 4);
    for (size_t i = 0; i < sphere_count; ++i) {
        const float *s = spheres + 4 * i;
        if (!finite_floats(s, 4, &bad))
            return sk_fail(error, SK_ERROR_NOT_FINITE, "sphere %zu has a NaN or infinity", i);
        if (s[3] < 0.0f)
            return sk_fail(error, SK_ERROR_ARGUMENT, "sphere %zu has a negative radius %g", i, (double)s[3]);
        uint8_t inside = 1;
        for (size_t p = 0; p < plane_count && inside; ++p) {
            const float *n = planes + 4 * p;
            /* double: a sphere exactly touching a plane must not be lost to float rounding */
            const double distance = (double)n[0] * s[0] + (double)n[1] * s[1] + (double)n[2] * s[2] + n[3];
            inside = distance >= -(double)s[3];
        }
        visible[i] = inside;
    }
    return sk_succeed(error);
}

static sk_status check_camera(const sk_runtime_camera *camera, float pixel_tolerance, double forward[3],
                              sk_error *error)
{
    if (!camera || !camera->position || !camera->forward)
        return sk_fail(error, SK_ERROR_ARGUMENT, "the camera's position and forward must not be null");
    size_t bad;
    if (!finite_floats(camera->position, 3, &bad) || !finite_floats(camera->forward, 3, &bad))
        return sk_fail(error, SK_ERROR_NOT_FINITE, "the camera's position or forward has a NaN or infinity");
    const double length = sqrt((double)camera->forward[0] * camera->forward[0] +
                               (double)camera->forward[1] * camera->forward[1] +
                               (double)camera->forward[2] * camera->forward[2]);
    if (fabs(length - 1.0) > 1e-3)
        return sk_fail(error, SK_ERROR_ARGUMENT, "the camera's forward has length %g, not 1", length);
    for (int c = 0; c < 3; ++c)
        forward[c] = camera->forward[c] / length;
    if (!(camera->horizontal_fov > 0.0f && camera->horizontal_fov < 3.14159265f))
        return sk_fail(error, SK_ERROR_ARGUMENT, "horizontal_fov %g is not in (0, pi)", (double)camera->horizontal_fov);
    if (!(camera->viewport_width > 0.0f && isfinite(camera->viewport_width)))
        return sk_fail(error, SK_ERROR_ARGUMENT, "viewport_width %g is not > 0", (double)camera->viewport_width);
    if (!(pixel_tolerance >= 0.0f && isfinite(pixel_tolerance)))
        return sk_fail(error, SK_ERROR_ARGUMENT, "pixel_tolerance %g is not >= 0", (double)pixel_tolerance);
    return SK_OK;
}

static sk_status check_epsilons(const float *eps, size_t instance, size_t level_count, sk_error *error)
{
    if (!(eps[0] == 0.0f))
        return sk_fail(error, SK_ERROR_ARGUMENT, "instance %zu: epsilon of level 0 is %g, not 0", instance,
                       (double)eps[0]);
    for (size_t k = 1; k < level_count; ++k)
        if (!(eps[k] >= eps[k - 1]))
            return sk_fail(error, SK_ERROR_ARGUMENT, "instance %zu: epsilon of level %zu (%g) is below level %zu's",
                           instance, k, (double)eps[k], k - 1);
    return SK_OK;
}

/* The real level whose linearly interpolated epsilon is `allowed`, clamped to the last finite level. */
static float level_for(const float *eps, size_t level_count, double allowed)
{
    size_t k = 0;
    while (k + 1 < level_count && isfinite(eps[k + 1]) && eps[k + 1] <= allowed)
        ++k;
    if (k + 1 == level_count || !isfinite(eps[k + 1]))
        return (float)k;
    const double fraction = (allowed - eps[k]) / ((double)eps[k + 1] - eps[k]);
    /* float rounding may round k + fraction up past the allowed error: step down to the float below */
    float level = (float)((double)k + fraction);
    while (level > (float)k && eps[k] + ((double)level - k) * ((double)eps[k + 1] - eps[k]) > allowed)
        level = nextafterf(level, (float)k);
    return level;
}

sk_status sk_runtime_select_levels(float *levels, const float *spheres, const float *epsilons, size_t instance_count,
                                   size_t level_count, const sk_runtime_camera *camera, float pixel_tolerance,
                                   sk_error *error)
{
    if (!levels || (instance_count && (!spheres || !epsilons)))
        return sk_fail(error, SK_ERROR_ARGUMENT, "levels, spheres and epsilons must not be null");
    if (level_count == 0)
        return sk_fail(error, SK_ERROR_ARGUMENT, "level selection needs at least one level");
    double forward[3] = {0.0, 0.0, 0.0};
    sk_status status = check_camera(camera, pixel_tolerance, forward, error);
    if (status != SK_OK)
        return status;
    const double scale = 2.0 * pixel_tolerance * sin(0.5 * camera->horizontal_fov) / camera->viewport_width;
    const float *eye = camera->position;
    for (size_t i = 0; i < instance_count; ++i) {
        const float *s = spheres + 4 * i, *eps = epsilons + level_count * i;
        size_t bad;
        if (!finite_floats(s, 4, &bad) || s[3] < 0.0f)
            return sk_fail(error, SK_ERROR_ARGUMENT, "sphere %zu is not finite with a radius >= 0", i);
        if ((status = check_epsilons(eps, i, level_count, error)) != SK_OK)
            return status;
        const double depth = forward[0] * (s[0] - eye[0]) + forward[1] * (s[1] - eye[1]) +
                             forward[2] * (s[2] - eye[2]) - s[3];
        levels[i] = level_for(eps, level_count, depth > 0.0 ? scale * depth : 0.0);
    }
    return sk_succeed(error);
}

sk_status sk_runtime_morph_uv(float *destination, const float *uv_morph, size_t corner_count, float fraction,
                              sk_error *error)
{
    if (!destination || (!uv_morph && corner_count))
        return sk_fail(error, SK_ERROR_ARGUMENT, "destination and uv_morph must not be null");
    if (!(fraction >= 0.0f && fraction <= 1.0f))
        return sk_fail(error, SK_ERROR_ARGUMENT, "fraction %g is not in [0, 1]", (double)fraction);
    for (size_t c = 0; c < corner_count; ++c) {
        destination[2 * c] = uv_morph[4 * c] + fraction * uv_morph[4 * c + 2];
        destination[2 * c + 1] = uv_morph[4 * c + 1] + fraction * uv_morph[4 * c + 3];
    }
    return sk_succeed(error);
}
