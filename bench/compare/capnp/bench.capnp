# The icars-compare workloads in Cap'n Proto's schema language (bench/compare/system.h): the Bench
# interface a server offers as its bootstrap capability, and the Subscriber callback a client
# passes to it, which the server then calls over that client's own connection.
@0x83a5490060b27239;

using Cxx = import "/capnp/c++.capnp";
# Not `icarsbench`, Ice's module: both are linked into icars-compare.
$Cxx.namespace("icars::compare_capnp");

interface Subscriber {
  event @0 (seq :UInt64, payload :Data);
  # One published event; answered once counted.
}

interface Bench {
  echoInt @0 (x :Int32) -> (x :Int32);
  sizeOf @1 (data :Data) -> (size :UInt64);
  echoBytes @2 (data :Data) -> (data :Data);

  subscribe @3 (subscriber :Subscriber);
  # Registers `subscriber` for every later publish; answered once registered. The server drops it
  # when a call to it fails (its connection is gone).

  publish @4 (count :Int32, payloadSize :UInt32);
  # Calls event() on every subscriber `count` times with `payloadSize` bytes; answered once the
  # calls are queued, not delivered.
}
