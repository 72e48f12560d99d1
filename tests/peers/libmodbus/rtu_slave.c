/* A libmodbus RTU slave: a peer nobody here wrote the framing of.
 *
 * libmodbus frames only the function codes it implements (here: what modbus_reply serves, with
 * no diagnostics): a request of any other function it takes for a short frame with a wrong CRC
 * and stays silent, as many meters and I/O modules built on it do. Serves holding registers
 * 0..99 = 1000H + n and input registers 0..99 = 2000H + n at the given unit id.
 *
 * usage: rtu_slave DEVICE UNIT_ID
 */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <modbus/modbus.h>

int main(int argc, char **argv) {
    if (argc != 3) {
        fprintf(stderr, "usage: %s DEVICE UNIT_ID\n", argv[0]);
        return 2;
    }
    modbus_t *ctx = modbus_new_rtu(argv[1], 19200, 'E', 8, 1);
    modbus_mapping_t *map = modbus_mapping_new(0, 0, 100, 100);
    if (ctx == NULL || map == NULL) {
        fprintf(stderr, "libmodbus: %s\n", modbus_strerror(errno));
        return 1;
    }
    for (int i = 0; i < 100; i++) {
        map->tab_registers[i] = 0x1000 + i;
        map->tab_input_registers[i] = 0x2000 + i;
    }
    modbus_set_slave(ctx, atoi(argv[2]));
    if (modbus_connect(ctx) == -1) {
        fprintf(stderr, "libmodbus: %s\n", modbus_strerror(errno));
        return 1;
    }
    printf("ready\n");
    fflush(stdout);
    uint8_t query[MODBUS_RTU_MAX_ADU_LENGTH];
    for (;;) {
        int rc = modbus_receive(ctx, query);
        if (rc > 0) {
            modbus_reply(ctx, query, rc, map);
        }
        /* rc == -1: a frame it could not take (bad CRC, unknown function): silence. */
    }
}
