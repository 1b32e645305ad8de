"""Any Modbus device from a YAML description: node, simulator, docs."""
