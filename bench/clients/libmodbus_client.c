/* libmodbus client of bench/pty_clients.sh: reads 2 registers at 2100H from drive 1 (Modbus
 * RTU) in a tight loop for SECONDS and prints reads/s and latency percentiles. */
#include <errno.h>
#include <modbus.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

#include "timing.h"

int main(int argc, char **argv) {
    if (argc < 3) {
        fprintf(stderr, "usage: libmodbus_client PORT SECONDS\n");
        return 3;
    }
    double seconds = atof(argv[2]);
    modbus_t *ctx = modbus_new_rtu(argv[1], 115200, 'N', 8, 1);
    if (ctx == NULL || modbus_set_slave(ctx, 1) != 0 || modbus_connect(ctx) != 0) {
        fprintf(stderr, "libmodbus_client: cannot open %s: %s\n", argv[1], modbus_strerror(errno));
        return 2;
    }
    modbus_set_response_timeout(ctx, 0, 500000);
    size_t cap = 1 << 22, n = 0;
    double *lat = malloc(cap * sizeof(double));
    long errors = 0;
    uint16_t regs[2];
    double start = now_s(), end = start + seconds;
    while (now_s() < end) {
        double t0 = now_s();
        if (modbus_read_registers(ctx, 0x2100, 2, regs) == 2) {
            if (n < cap) lat[n++] = now_s() - t0;
        } else {
            errors++;
        }
    }
    double elapsed = now_s() - start;
    qsort(lat, n, sizeof(double), cmp);
    double p50 = n ? lat[(size_t)(n * 0.50)] * 1e6 : 0, p99 = n ? lat[(size_t)(n * 0.99)] * 1e6 : 0;
    printf("libmodbus reads=%zu errors=%ld seconds=%.2f reads_per_s=%.0f p50_us=%.1f p99_us=%.1f\n", n, errors,
           elapsed, n / elapsed, p50, p99);
    modbus_close(ctx);
    modbus_free(ctx);
    return 0;
}
