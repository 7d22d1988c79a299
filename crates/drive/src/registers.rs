//! Register maps of drive families, shared by the masters (`profile`) and the simulators, so
//! both sides of the wire read the same table.

/// The generic VFD of `seeds/004_e8ea1998fe1a671e.txt`: 2000H command, 2001H frequency,
/// 2100H–210BH monitors, 2101H status bits.
pub mod generic {
    /// The silence before and after every RTU frame: seed 004's "保持无输入信号大于等于 10ms"
    /// (no signal for at least 10 ms), longer than t3.5 at every baud rate from 4800 up.
    pub const FRAME_SILENCE: core::time::Duration = core::time::Duration::from_millis(10);

    /// The silence a master keeps before each request on a line of `family` drives speaking
    /// `protocol`, where the family's manual asks for more than the protocol's own:
    /// [`FRAME_SILENCE`] for the generic drive in Modbus RTU.
    pub fn line_silence(
        family: crate::Family,
        protocol: drivebus_proto::protocol::WireProtocol,
    ) -> Option<core::time::Duration> {
        (family == crate::Family::Generic && protocol == drivebus_proto::protocol::WireProtocol::ModbusRtu)
            .then_some(FRAME_SILENCE)
    }

    /// The registers of the seed's map ("通讯协议参数定义").
    pub mod reg {
        /// 2000H: command (06): 1 run, 2 forward run, 3 reverse run, 4 jog, 5 jog forward,
        /// 6 jog reverse, 7 decelerate to stop, 8 emergency stop, 9 jog stop, 0AH fault reset.
        pub const COMMAND: u16 = 0x2000;
        /// 2001H: frequency setting from the serial port, 0.01 Hz ("串口设置频率命令").
        pub const FREQUENCY: u16 = 0x2001;
        /// 2100H: fault code.
        pub const FAULT_CODE: u16 = 0x2100;
        /// 2101H: status bits.
        pub const STATUS: u16 = 0x2101;
        /// 2102H: set frequency, 0.01 Hz.
        pub const SET_FREQUENCY: u16 = 0x2102;
        /// 2103H: output frequency, 0.01 Hz.
        pub const OUTPUT_FREQUENCY: u16 = 0x2103;
        /// 2104H: output current, 0.1 A.
        pub const OUTPUT_CURRENT: u16 = 0x2104;
        /// 2105H: DC bus voltage, 0.1 V.
        pub const DC_BUS_VOLTAGE: u16 = 0x2105;
        /// 2106H: output voltage, 1 V.
        pub const OUTPUT_VOLTAGE: u16 = 0x2106;
        /// 2107H: motor speed, rpm.
        pub const MOTOR_SPEED: u16 = 0x2107;
        /// 2108H: module temperature, 0.1 degC (signed).
        pub const MODULE_TEMPERATURE: u16 = 0x2108;
        /// 2109H: VI analog input, 0.01 V.
        pub const VI_INPUT: u16 = 0x2109;
        /// 210AH: CI analog input, 0.01 mA.
        pub const CI_INPUT: u16 = 0x210A;
        /// 210BH: software version, BCD (0x0100 = 1.00).
        pub const VERSION: u16 = 0x210B;
    }

    /// The values of the command register 2000H.
    pub mod command {
        /// 0001H: run (in the commanded direction).
        pub const RUN: u16 = 0x0001;
        /// 0002H: forward run.
        pub const FORWARD_RUN: u16 = 0x0002;
        /// 0003H: reverse run.
        pub const REVERSE_RUN: u16 = 0x0003;
        /// 0004H: jog.
        pub const JOG: u16 = 0x0004;
        /// 0005H: jog forward.
        pub const JOG_FORWARD: u16 = 0x0005;
        /// 0006H: jog reverse.
        pub const JOG_REVERSE: u16 = 0x0006;
        /// 0007H: decelerate to stop.
        pub const DECELERATE_TO_STOP: u16 = 0x0007;
        /// 0008H: emergency stop.
        pub const EMERGENCY_STOP: u16 = 0x0008;
        /// 0009H: jog stop.
        pub const JOG_STOP: u16 = 0x0009;
        /// 000AH: fault reset.
        pub const FAULT_RESET: u16 = 0x000A;
    }

    /// Bits of the status register 2101H ("读变频器状态").
    pub mod status {
        /// BIT0: running ("运行停止标志, 1: 运行").
        pub const RUN: u16 = 1 << 0;
        /// BIT1: undervoltage.
        pub const UNDERVOLTAGE: u16 = 1 << 1;
        /// BIT2: reverse ("正反转标志, 1: 反转").
        pub const REVERSE: u16 = 1 << 2;
        /// BIT3: jog.
        pub const JOG: u16 = 1 << 3;
        /// BIT4: closed-loop control (never set: not simulated).
        pub const CLOSED_LOOP: u16 = 1 << 4;
        /// BIT5: wobble frequency mode (never set: not simulated).
        pub const WOBBLE: u16 = 1 << 5;
        /// BIT6: PLC running (never set: not simulated).
        pub const PLC: u16 = 1 << 6;
        /// BIT7: multi-step speed from terminals (running with P0.00 = 5).
        pub const MULTI_STEP: u16 = 1 << 7;
        /// BIT8: normal running (running, not jogging).
        pub const NORMAL_RUN: u16 = 1 << 8;
        /// BIT9: main frequency from the communication interface (P0.00 = 4).
        pub const FREQUENCY_FROM_COMM: u16 = 1 << 9;
        /// BIT10: main frequency from an analog input (P0.00 = 2 or 3).
        pub const FREQUENCY_FROM_ANALOG: u16 = 1 << 10;
        /// BIT11: run command from the communication interface (P0.01 = 2).
        pub const RUN_FROM_COMM: u16 = 1 << 11;
        /// BIT12: parameters password protected (P0.15 not 0).
        pub const PROTECTED: u16 = 1 << 12;
    }
}
