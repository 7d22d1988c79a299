/* The bare client of bench/pty_clients.sh: the least a Modbus RTU master can do per read over
 * a pty (one write(2) of a prebuilt request, blocking read(2) until the 9-byte reply is in, no
 * checks), reading 2 registers at 2100H from drive 1 for SECONDS. Usage: pty_floor_client PORT
 * SECONDS. */
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include "timing.h"

int main(int argc, char **argv) {
    if (argc < 3) {
        fprintf(stderr, "usage: pty_floor_client PORT SECONDS\n");
        return 3;
    }
    int fd = open(argv[1], O_RDWR | O_NOCTTY);
    if (fd < 0) {
        perror("pty_floor_client: open");
        return 2;
    }
    struct termios t;
    tcgetattr(fd, &t);
    cfmakeraw(&t);
    t.c_cc[VMIN] = 1;
    t.c_cc[VTIME] = 0;
    tcsetattr(fd, TCSANOW, &t);
    static const unsigned char req[8] = {0x01, 0x03, 0x21, 0x00, 0x00, 0x02, 0xCE, 0x37};
    unsigned char buf[64];
    size_t cap = 1 << 22, n = 0;
    double *lat = malloc(cap * sizeof(double));
    double start = now_s(), end = start + atof(argv[2]), t0 = start;
    while (t0 < end) {
        if (write(fd, req, sizeof req) != (ssize_t)sizeof req) {
            perror("pty_floor_client: write");
            return 2;
        }
        int got = 0;
        while (got < 9) {
            int r = read(fd, buf + got, sizeof buf - got);
            if (r <= 0) {
                perror("pty_floor_client: read");
                return 2;
            }
            got += r;
        }
        double t1 = now_s();
        if (n < cap) lat[n++] = t1 - t0;
        t0 = t1;
    }
    double elapsed = now_s() - start;
    qsort(lat, n, sizeof(double), cmp);
    printf("bare-c reads=%zu errors=0 seconds=%.2f reads_per_s=%.0f p50_us=%.1f p99_us=%.1f\n", n, elapsed,
           n / elapsed, n ? lat[(size_t)(n * 0.50)] * 1e6 : 0, n ? lat[(size_t)(n * 0.99)] * 1e6 : 0);
    return 0;
}
