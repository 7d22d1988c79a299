//! MQTT (placeholder).
