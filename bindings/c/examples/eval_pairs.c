/* Loads a BRDF table (or any source brdfpack opens) and prints f_r at direction pairs.
 *
 *   eval_pairs SOURCE                 three fixed pairs, one row each: the channel values
 *   eval_pairs SOURCE - < pairs.txt   pairs from stdin, `wix wiy wiz wox woy woz` per line
 *   eval_pairs --memory FILE          reads FILE into memory and opens it from the buffer
 *
 * Values are printed with 17 significant digits (each parses back to the same double), so
 * they can be compared bit for bit with `brdfpack eval SOURCE --input text`. On an error
 * it prints brdfpack's message and the error code and exits with 2 (bad input) or 1. */
#include "brdfpack.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static int fail(const char *what, int32_t code) {
    fprintf(stderr, "%s failed with code %d: %s\n", what, (int)code, brdfpack_last_error());
    return code == BRDFPACK_ERROR_INPUT || code == BRDFPACK_ERROR_INVALID_FILE ? 2 : 1;
}

/* Reads a whole file into a malloc'ed buffer; NULL on failure. */
static unsigned char *read_file(const char *path, size_t *len) {
    FILE *f = fopen(path, "rb");
    if (!f) return NULL;
    size_t cap = 1 << 16, n = 0;
    unsigned char *buf = malloc(cap);
    while (buf) {
        n += fread(buf + n, 1, cap - n, f);
        if (n < cap) break;
        unsigned char *bigger = realloc(buf, cap * 2);
        if (!bigger) { free(buf); buf = NULL; break; }
        buf = bigger;
        cap *= 2;
    }
    fclose(f);
    *len = n;
    return buf;
}

int main(int argc, char **argv) {
    if (argc < 2) {
        fprintf(stderr, "usage: %s SOURCE [-] | --memory FILE\n", argv[0]);
        return 2;
    }
    if (brdfpack_abi_version() != BRDFPACK_ABI_VERSION) {
        fprintf(stderr, "header ABI %d, library ABI %u\n", BRDFPACK_ABI_VERSION,
                (unsigned)brdfpack_abi_version());
        return 1;
    }
    BrdfpackSource *src = NULL;
    int32_t rc;
    int from_stdin = 0;
    if (strcmp(argv[1], "--memory") == 0 && argc >= 3) {
        size_t len = 0;
        unsigned char *bytes = read_file(argv[2], &len);
        if (!bytes) {
            fprintf(stderr, "cannot read %s\n", argv[2]);
            return 2;
        }
        rc = brdfpack_open_memory(bytes, len, argv[2], &src);
        free(bytes); /* the source keeps what it needs */
        if (rc != BRDFPACK_OK) return fail("brdfpack_open_memory", rc);
        from_stdin = argc >= 4 && strcmp(argv[3], "-") == 0;
    } else {
        rc = brdfpack_open(argv[1], &src);
        if (rc != BRDFPACK_OK) return fail("brdfpack_open", rc);
        from_stdin = argc >= 3 && strcmp(argv[2], "-") == 0;
    }

    size_t channels = 0;
    if ((rc = brdfpack_channels(src, &channels)) != BRDFPACK_OK) return fail("brdfpack_channels", rc);
    size_t ndims = 0, dims[4] = {0, 0, 0, 0};
    rc = brdfpack_grid_shape(src, &ndims, dims);
    if (rc == BRDFPACK_OK) {
        size_t count = 0;
        if ((rc = brdfpack_table_data(src, NULL, 0, &count)) != BRDFPACK_OK)
            return fail("brdfpack_table_data", rc);
        float *data = malloc(count * sizeof(float));
        if (!data) return 1;
        if ((rc = brdfpack_table_data(src, data, count, &count)) != BRDFPACK_OK)
            return fail("brdfpack_table_data", rc);
        fprintf(stderr, "table: %zu axes (", ndims);
        for (size_t k = 0; k < ndims; k++) fprintf(stderr, k ? "x%zu" : "%zu", dims[k]);
        fprintf(stderr, "), %zu channels, %zu floats decoded\n", channels, count);
        free(data);
    } else if (rc != BRDFPACK_ERROR_NOT_A_TABLE) {
        return fail("brdfpack_grid_shape", rc);
    }

    /* The pairs: three fixed ones, or the lines of stdin. */
    size_t cap = 3, n = 0;
    double *wi = malloc(3 * cap * sizeof(double)), *wo = malloc(3 * cap * sizeof(double));
    if (!wi || !wo) return 1;
    if (from_stdin) {
        double v[6];
        while (scanf("%lf %lf %lf %lf %lf %lf", &v[0], &v[1], &v[2], &v[3], &v[4], &v[5]) == 6) {
            if (n == cap) {
                cap *= 2;
                double *a = realloc(wi, 3 * cap * sizeof(double));
                double *b = realloc(wo, 3 * cap * sizeof(double));
                if (!a || !b) return 1;
                wi = a;
                wo = b;
            }
            memcpy(wi + 3 * n, v, 3 * sizeof(double));
            memcpy(wo + 3 * n, v + 3, 3 * sizeof(double));
            n++;
        }
    } else {
        const double fixed[3][6] = {
            {0.0, 0.0, 1.0, 0.0, 0.0, 1.0},
            {0.5, 0.0, 0.8660254037844386, -0.5, 0.0, 0.8660254037844386},
            {0.3, 0.4, 0.8660254037844386, 0.1, -0.6, 0.7937253933193772},
        };
        for (n = 0; n < 3; n++) {
            memcpy(wi + 3 * n, fixed[n], 3 * sizeof(double));
            memcpy(wo + 3 * n, fixed[n] + 3, 3 * sizeof(double));
        }
    }
    double *f = malloc((n ? n : 1) * channels * sizeof(double));
    if (!f) return 1;
    /* Flags 0: tables take the batched lookup, which gives the bits `brdfpack eval` prints
       (BRDFPACK_EVAL_EXACT would evaluate pair by pair, with the same result). */
    rc = brdfpack_eval(src, wi, wo, n, f, n * channels, 0);
    if (rc != BRDFPACK_OK) return fail("brdfpack_eval", rc);
    for (size_t p = 0; p < n; p++) {
        for (size_t c = 0; c < channels; c++)
            printf(c ? " %.17g" : "%.17g", f[p * channels + c]);
        printf("\n");
    }
    free(f);
    free(wi);
    free(wo);
    brdfpack_free(src);
    return 0;
}
