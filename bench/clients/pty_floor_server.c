/* The floor of bench/pty_clients.sh (SERVER=floor): a pty whose only work is to answer every
 * 8-byte Modbus RTU read (FC 03/04) with fixed register values, blocking in read(2) between
 * requests. No line model, no drive: what a client reaches against it is what the pty and the
 * scheduler allow. Usage: pty_floor_server LINK (prints "listening on DEVICE"). */
#define _GNU_SOURCE
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>
#include <unistd.h>

static unsigned short crc16(const unsigned char *p, int n) {
    unsigned short c = 0xFFFF;
    for (int i = 0; i < n; i++) {
        c ^= p[i];
        for (int b = 0; b < 8; b++) c = (c & 1) ? (c >> 1) ^ 0xA001 : c >> 1;
    }
    return c;
}

int main(int argc, char **argv) {
    if (argc < 2) {
        fprintf(stderr, "usage: pty_floor_server LINK\n");
        return 3;
    }
    int m = posix_openpt(O_RDWR | O_NOCTTY);
    if (m < 0 || grantpt(m) != 0 || unlockpt(m) != 0) {
        perror("pty_floor_server: posix_openpt");
        return 2;
    }
    char *name = ptsname(m);
    int s = open(name, O_RDWR | O_NOCTTY); /* kept open: the master never sees EIO */
    struct termios t;
    tcgetattr(s, &t);
    cfmakeraw(&t);
    tcsetattr(s, TCSANOW, &t);
    unlink(argv[1]);
    if (symlink(name, argv[1]) != 0) {
        perror("pty_floor_server: symlink");
        return 2;
    }
    printf("listening on %s\n", name);
    fflush(stdout);
    unsigned char buf[512];
    int len = 0;
    for (;;) {
        int n = read(m, buf + len, sizeof buf - len);
        if (n <= 0) continue;
        len += n;
        while (len >= 8) {
            unsigned char r[300];
            int count = buf[5] > 125 ? 125 : buf[5];
            r[0] = buf[0];
            r[1] = buf[1];
            r[2] = (unsigned char)(2 * count);
            for (int i = 0; i < 2 * count; i++) r[3 + i] = (unsigned char)i;
            int rl = 3 + 2 * count;
            unsigned short c = crc16(r, rl);
            r[rl++] = c & 0xFF;
            r[rl++] = c >> 8;
            if (write(m, r, rl) != rl) perror("pty_floor_server: write");
            memmove(buf, buf + 8, len - 8);
            len -= 8;
        }
    }
}
