/*
 * The helpers in csrc/common every family shares: overflow-checked sizes (and the refusal of counts whose
 * arrays cannot exist), the grow-on-push arrays, and the LAPACK-free 3x3 SVD and polar factor.
 */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "sk_internal.h"
#include "sk_math.h"
#include "test_support.h"

static void test_sizes(void)
{
    size_t out = 0;
    CHECK(sk_mul_size(3, 5, &out) && out == 15);
    CHECK(sk_mul_size(SIZE_MAX, 0, &out) && out == 0);
    CHECK(!sk_mul_size(SIZE_MAX / 2 + 1, 2, &out) && out == SIZE_MAX);
    CHECK(sk_add_size(SIZE_MAX - 1, 1, &out) && out == SIZE_MAX);
    CHECK(!sk_add_size(SIZE_MAX, 1, &out) && out == SIZE_MAX);
    CHECK(sk_array_size(&out, 4, 5, 6, "test", NULL) == SK_OK && out == 120);
    EXPECT_FAILURE("array size overflow", SK_ERROR_ARGUMENT, sk_array_size(&out, SIZE_MAX / 8, 16, 1, "test", error));
    CHECK(sk_allocate(SIZE_MAX / 4, 8) == NULL);
    void *empty = sk_allocate(0, 8); /* a real block, so NULL always means failure */
    CHECK(empty != NULL);
    free(empty);
}

/* Counts whose arrays could not exist are refused before anything is read, not wrapped round. */
static void test_huge_counts_are_refused(void)
{
    const int32_t offsets[2] = {0, 1}, bones[1] = {0};
    const double coordinates[4] = {0, 0, 0, 1}, poses[16] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};
    double out[3];
    const sk_influences influences = {offsets, bones, 1, 1};
    EXPECT_FAILURE("evaluation with 2^61 bones", SK_ERROR_ARGUMENT,
                   sk_animation_space_evaluate_f64(out, &influences, coordinates, poses, SIZE_MAX / 8, 1, error));
    const sk_examples examples = {poses, coordinates, SIZE_MAX / 2, 1};
    double fitted[4];
    EXPECT_FAILURE("fit with 2^63 examples", SK_ERROR_ARGUMENT,
                   sk_fit_per_vertex(fitted, &influences, &examples, NULL, 0.0, 1, error));
    sk_error record = empty_error();
    sk_fit_per_vertex(fitted, &influences, &examples, NULL, 0.0, 1, &record);
    CHECK_IN(record.message, strstr(record.message, "does not fit in memory") != NULL);
}

typedef struct int_list {
    int *items;
    size_t size, capacity;
} int_list;

static void test_push(void)
{
    int_list list = {NULL, 0, 0};
    int ok = 1;
    for (int i = 0; i < 1000; ++i)
        ok &= SK_PUSH(list, i * i, 4);
    CHECK(ok && list.size == 1000 && list.capacity == 1024);
    int right = 1;
    for (int i = 0; i < 1000; ++i)
        right &= list.items[i] == i * i;
    CHECK(right);
    free(list.items);
}

/* a = U diag(s) V^T with U, V orthogonal and s descending, to rounding of the largest singular value. */
static void check_svd(const char *context, const double a[9])
{
    double s[3], u[9], v[9];
    sk_svd3(s, u, v, a);
    double largest = 0.0, worst = 0.0, orthogonality = 0.0;
    for (int k = 0; k < 9; ++k)
        largest = fmax(largest, fabs(a[k]));
    for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) {
            double product = 0.0, uu = 0.0, vv = 0.0;
            for (int k = 0; k < 3; ++k) {
                product += u[3 * r + k] * s[k] * v[3 * c + k];
                uu += u[3 * k + r] * u[3 * k + c];
                vv += v[3 * k + r] * v[3 * k + c];
            }
            worst = fmax(worst, fabs(product - a[3 * r + c]));
            orthogonality = fmax(orthogonality, fmax(fabs(uu - (r == c)), fabs(vv - (r == c))));
        }
    CHECK_IN(context, worst <= 1e-14 * fmax(largest, 1e-300) + 1e-300);
    CHECK_IN(context, orthogonality < 1e-13);
    CHECK_IN(context, s[0] >= s[1] && s[1] >= s[2] && s[2] >= 0.0);
}

static void test_svd(void)
{
    for (int trial = 0; trial < 200; ++trial) {
        double a[9];
        for (int k = 0; k < 9; ++k)
            a[k] = random_uniform(-2.0, 2.0);
        check_svd("random", a);
    }
    /* rotation * diag(scales) * rotation: the singular values are the scales, even 1e12 apart */
    const double scales[3][3] = {{3.0, 1e-6, 1e-12}, {1.0, 1.0, 1.0}, {2.0, 0.0, 0.0}};
    for (int i = 0; i < 3; ++i) {
        double r1[9], r2[9], a[9], s[3];
        random_rotation(r1);
        random_rotation(r2);
        for (int r = 0; r < 3; ++r)
            for (int c = 0; c < 3; ++c) {
                a[3 * r + c] = 0.0;
                for (int k = 0; k < 3; ++k)
                    a[3 * r + c] += r1[3 * r + k] * scales[i][k] * r2[3 * k + c];
            }
        check_svd("scaled rotations", a);
        sk_svd3(s, NULL, NULL, a);
        for (int k = 0; k < 3; ++k)
            CHECK_IN("singular values", fabs(s[k] - scales[i][k]) <= 1e-15 * 3.0 + 1e-12 * scales[i][k]);
    }
    const double zero[9] = {0};
    check_svd("zero", zero);
    const double rank_one[9] = {1, 2, 3, 2, 4, 6, -1, -2, -3};
    check_svd("rank one", rank_one);
}

static void test_nearest_rotation(void)
{
    for (int trial = 0; trial < 50; ++trial) {
        double rotation[9], stretched[9], nearest[9];
        random_rotation(rotation);
        /* rotation * (symmetric positive definite): the polar factor is the rotation */
        const double spd[9] = {2.0, 0.3, 0.1, 0.3, 1.5, -0.2, 0.1, -0.2, 0.7};
        for (int r = 0; r < 3; ++r)
            for (int c = 0; c < 3; ++c) {
                stretched[3 * r + c] = 0.0;
                for (int k = 0; k < 3; ++k)
                    stretched[3 * r + c] += rotation[3 * r + k] * spd[3 * k + c];
            }
        sk_nearest_rotation3(nearest, stretched);
        CHECK(max_abs_difference(nearest, rotation, 9) < 1e-12);
    }
    const double mirror[9] = {1, 0, 0, 0, 1, 0, 0, 0, -0.1}; /* a reflection: the smallest direction flips */
    double nearest[9];
    sk_nearest_rotation3(nearest, mirror);
    const double identity[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};
    CHECK(max_abs_difference(nearest, identity, 9) < 1e-14 && fabs(sk_determinant3(nearest) - 1.0) < 1e-14);
}

int main(void)
{
    test_program_name = "test_common";
    test_sizes();
    test_huge_counts_are_refused();
    test_push();
    test_svd();
    test_nearest_rotation();
    return finish_tests();
}
