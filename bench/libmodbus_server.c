/* A libmodbus Modbus TCP server for bench/gateway_load.sh: ten input registers (the same
 * count the gateway serves per unit), modbus_tcp_listen and a select loop over every client,
 * as libmodbus' own tests/bandwidth-server-many-up.c does.
 *
 * cc -O2 -o libmodbus_server bench/libmodbus_server.c $(pkg-config --cflags --libs libmodbus)
 * ./libmodbus_server PORT
 */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <sys/select.h>
#include <sys/socket.h>
#include <unistd.h>

#include <modbus.h>

int main(int argc, char **argv) {
    int port = argc > 1 ? atoi(argv[1]) : 1502;
    modbus_t *ctx = modbus_new_tcp("127.0.0.1", port);
    modbus_mapping_t *map = modbus_mapping_new(0, 0, 10, 10);
    if (ctx == NULL || map == NULL) {
        fprintf(stderr, "libmodbus_server: %s\n", modbus_strerror(errno));
        return 1;
    }
    for (int i = 0; i < 10; i++) {
        map->tab_input_registers[i] = (uint16_t)(i * 100);
    }
    int server = modbus_tcp_listen(ctx, 1024);
    if (server < 0) {
        fprintf(stderr, "libmodbus_server: listen: %s\n", modbus_strerror(errno));
        return 1;
    }
    printf("listening on 127.0.0.1:%d\n", port);
    fflush(stdout);
    fd_set refset, rdset;
    FD_ZERO(&refset);
    FD_SET(server, &refset);
    int fdmax = server;
    uint8_t query[MODBUS_TCP_MAX_ADU_LENGTH];
    for (;;) {
        rdset = refset;
        if (select(fdmax + 1, &rdset, NULL, NULL, NULL) == -1) {
            perror("select");
            return 1;
        }
        for (int fd = 0; fd <= fdmax; fd++) {
            if (!FD_ISSET(fd, &rdset)) {
                continue;
            }
            if (fd == server) {
                int client = accept(server, NULL, NULL);
                if (client == -1) {
                    continue;
                }
                if (client >= FD_SETSIZE) { /* select cannot watch it */
                    close(client);
                    continue;
                }
                FD_SET(client, &refset);
                if (client > fdmax) {
                    fdmax = client;
                }
            } else {
                modbus_set_socket(ctx, fd);
                int rc = modbus_receive(ctx, query);
                if (rc > 0) {
                    modbus_reply(ctx, query, rc, map);
                } else if (rc == -1) {
                    close(fd);
                    FD_CLR(fd, &refset);
                    if (fd == fdmax) {
                        fdmax--;
                    }
                }
            }
        }
    }
}
