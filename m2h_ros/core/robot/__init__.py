"""Moving a robot base: the discrete actions carried out closed-loop on odometry."""
