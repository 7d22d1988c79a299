/* The floor of bench/gateway_load.sh: a Modbus TCP server that does the least a server can do
 * per request (one epoll loop, one recv(2) and one send(2), input or holding registers answered
 * with fixed values, no checks beyond framing). What the load generator measures against it is
 * what the kernel's loopback TCP path allows one core. Usage: modbus_floor_server PORT. */
#define _GNU_SOURCE
#include <arpa/inet.h>
#include <errno.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/epoll.h>
#include <sys/socket.h>
#include <unistd.h>

int main(int argc, char **argv) {
    if (argc < 2) {
        fprintf(stderr, "usage: modbus_floor_server PORT\n");
        return 3;
    }
    int ls = socket(AF_INET, SOCK_STREAM | SOCK_NONBLOCK, 0), one = 1;
    setsockopt(ls, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
    struct sockaddr_in a = {.sin_family = AF_INET, .sin_port = htons(atoi(argv[1])),
                            .sin_addr.s_addr = htonl(INADDR_LOOPBACK)};
    if (bind(ls, (struct sockaddr *)&a, sizeof a) != 0 || listen(ls, 4096) != 0) {
        perror("modbus_floor_server: bind");
        return 2;
    }
    int ep = epoll_create1(0);
    struct epoll_event ev = {.events = EPOLLIN, .data.fd = ls}, evs[256];
    epoll_ctl(ep, EPOLL_CTL_ADD, ls, &ev);
    unsigned char in[2048], out[2048];
    for (;;) {
        int n = epoll_wait(ep, evs, 256, -1);
        for (int i = 0; i < n; i++) {
            int fd = evs[i].data.fd;
            if (fd == ls) {
                int c;
                while ((c = accept4(ls, NULL, NULL, SOCK_NONBLOCK)) >= 0) {
                    setsockopt(c, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
                    struct epoll_event ce = {.events = EPOLLIN, .data.fd = c};
                    epoll_ctl(ep, EPOLL_CTL_ADD, c, &ce);
                }
                continue;
            }
            ssize_t r = recv(fd, in, sizeof in, 0);
            if (r <= 0) {
                if (r < 0 && errno == EAGAIN) continue;
                close(fd);
                continue;
            }
            int pos = 0, o = 0;
            while (r - pos >= 12) { /* MBAP + FC 03/04 request */
                unsigned char *q = in + pos;
                int count = q[11] > 125 ? 125 : q[11];
                memcpy(out + o, q, 4);
                out[o + 4] = 0;
                out[o + 5] = (unsigned char)(3 + 2 * count);
                out[o + 6] = q[6];
                out[o + 7] = q[7];
                out[o + 8] = (unsigned char)(2 * count);
                memset(out + o + 9, 0, 2 * count);
                o += 9 + 2 * count;
                pos += 12;
            }
            if (o > 0 && send(fd, out, o, MSG_NOSIGNAL) < 0) close(fd);
        }
    }
}
