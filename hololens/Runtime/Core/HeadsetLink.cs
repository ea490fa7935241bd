// The headset's two UDP channels (docs/headset_wire_format.md): gaze, clock echoes and confirm
// presses up to gaze_bridge, display messages and clock pings down from the PC. Only the
// configured PC address is listened to.
//
// Threading contract. "The owner" is the thread that calls SendGaze, SendConfirm, Pump and
// Restart (in the app: Unity's main thread; Update drives them).
// - Clock.Now() is called on the owner only. Unity's clock (Time.realtimeSinceStartupAsDouble)
//   throws on any other thread, like most of UnityEngine.
// - The receive thread never calls the clock: a ping is answered there at once (so the echo's
//   t2..t3 holds no frame time) with its arrival and departure read from Stopwatch ticks, carried
//   onto the clock by (clock - ticks) as the owner last read both back to back. Between two such
//   reads (a frame) the two clocks drift apart by under a microsecond. Until the owner has read
//   the clock once, pings are not answered (dropped as "clock_unset").
// - Received and Rejected are called on the owner, from Pump, like DisplayState.EventShown: the
//   receive thread queues what it got (at most MaxQueued; more are counted in Overflow).
using System;
using System.Collections.Concurrent;
using System.Collections.Generic;
using System.Diagnostics;
using System.Net;
using System.Net.Sockets;
using System.Threading;

namespace FabricGuidance.Headset
{
    public sealed class HeadsetLink : IDisposable
    {
        public const int MaxQueued = 256;
        /// <summary>A confirm press is sent this many times, ConfirmRepeatS apart, with one press_id.</summary>
        public const int ConfirmSends = 3;
        public const double ConfirmRepeatS = 0.02;

        public readonly DisplayState Display;
        public IHeadsetClock Clock { get; private set; }
        int sent, skipped, echoes, displayReceived, dropped, overflow, confirms;
        public int Sent { get { return sent; } }
        public int Skipped { get { return skipped; } }
        public int Echoes { get { return Volatile.Read(ref echoes); } }
        public int DisplayReceived { get { return Volatile.Read(ref displayReceived); } }
        public int Dropped { get { return Volatile.Read(ref dropped); } }
        public int Overflow { get { return Volatile.Read(ref overflow); } }
        public int Confirms { get { return confirms; } }
        public readonly Dictionary<string, int> DroppedBy = new Dictionary<string, int>();
        /// <summary>On the owner, from Pump: each accepted downlink message (pings included).</summary>
        public Action<DownlinkMessage> Received;
        /// <summary>On the owner, from Pump: the reason of each dropped downlink datagram.</summary>
        public Action<string> Rejected;

        readonly IPAddress pc;
        readonly IPEndPoint uplink;
        readonly UdpClient up;
        readonly UdpClient down;
        readonly object sendLock = new object();
        readonly ConcurrentQueue<KeyValuePair<DownlinkMessage, string>> arrived = new ConcurrentQueue<KeyValuePair<DownlinkMessage, string>>();
        readonly List<KeyValuePair<double, byte[]>> repeats = new List<KeyValuePair<double, byte[]>>();
        Thread thread;
        volatile bool stopping;
        uint seq, pressId;
        // (clock - ticks) in seconds as the owner last read both, as the bits of a double (Interlocked
        // gives a torn-free 64-bit read on 32-bit ARM too); NaN until the first read.
        long clockMinusTicks = BitConverter.DoubleToInt64Bits(double.NaN);

        /// <param name="pcAddress">the PC running gaze_bridge; the only downlink sender accepted</param>
        /// <param name="uplinkPort">gaze_bridge's port (5005)</param>
        /// <param name="listen">where display messages arrive (port 5006; port 0: any free port)</param>
        /// <param name="clock">the headset clock of gaze stamps, echoes and presses; called on the owner only</param>
        /// <param name="display">the state display messages go to (a new one when null)</param>
        public HeadsetLink(IPAddress pcAddress, int uplinkPort, IPEndPoint listen, IHeadsetClock clock, uint firstSeq = 0,
                           DisplayState display = null)
        {
            pc = pcAddress;
            uplink = new IPEndPoint(pcAddress, uplinkPort);
            Clock = clock;
            seq = firstSeq;
            Display = display ?? new DisplayState();
            up = new UdpClient(pcAddress.AddressFamily);
            down = new UdpClient(listen);
            down.Client.ReceiveTimeout = 200;   // lets Dispose stop the thread
        }

        public IPEndPoint ListenEndPoint { get { return (IPEndPoint)down.Client.LocalEndPoint; } }
        public uint NextSeq { get { return seq; } }
        /// <summary>The stamp of the last gaze frame sent (the headset clock at capture).</summary>
        public double LastStamp { get; private set; }
        /// <summary>The stamp of the last confirm press (the headset clock when it was pressed).</summary>
        public double LastConfirmStamp { get; private set; }

        public void Start()
        {
            thread = new Thread(ReceiveLoop) { IsBackground = true, Name = "headset downlink" };
            thread.Start();
        }

        static double TickSeconds() { return Stopwatch.GetTimestamp() / (double)Stopwatch.Frequency; }

        /// <summary>On the owner: the clock now, noting (clock - ticks) for the receive thread.</summary>
        double Now()
        {
            double before = TickSeconds();
            double now = Clock.Now();
            double after = TickSeconds();
            Interlocked.Exchange(ref clockMinusTicks, BitConverter.DoubleToInt64Bits(now - 0.5 * (before + after)));
            return now;
        }

        /// <summary>On the owner: send one gaze frame stamped now; false (and counted) when it holds NaN or infinity.</summary>
        public bool SendGaze(GazeFrame frame)
        {
            double stamp = Now();
            byte[] data = GazeWire.Encode(seq, stamp, frame);
            if (data == null) { skipped++; return false; }
            LastStamp = stamp;
            Send(data);
            seq++;   // uint: wraps to 0 after 4294967295, as the format says
            sent++;
            return true;
        }

        /// <summary>On the owner: the wearer pressed confirm (clicker, air tap, a key). Stamped now; sent
        /// now and ConfirmSends - 1 more times from Pump. Returns the press_id.</summary>
        public uint SendConfirm()
        {
            double stamp = Now();
            uint id = pressId++;
            byte[] data = GazeWire.EncodeConfirm(id, stamp);
            LastConfirmStamp = stamp;
            Send(data);
            double due = TickSeconds();
            for (int i = 1; i < ConfirmSends; i++) repeats.Add(new KeyValuePair<double, byte[]>(due + i * ConfirmRepeatS, data));
            confirms++;
            return id;
        }

        /// <summary>On the owner, once a frame: note the clock, send due confirm repeats, apply the
        /// display messages that arrived, and call Received / Rejected. Returns the messages applied.</summary>
        public int Pump()
        {
            Now();
            double t = TickSeconds();
            for (int i = 0; i < repeats.Count;)
            {
                if (repeats[i].Key <= t) { Send(repeats[i].Value); repeats.RemoveAt(i); }
                else i++;
            }
            KeyValuePair<DownlinkMessage, string> item;
            while (arrived.TryDequeue(out item))
            {
                if (item.Key != null)
                {
                    var received = Received;
                    if (received != null) received(item.Key);
                }
                else
                {
                    var rejected = Rejected;
                    if (rejected != null) rejected(item.Value);
                }
            }
            return Display.Pump();
        }

        /// <summary>On the owner: the app started again: seq and press_id from 0 and, with them, a new clock.</summary>
        public void Restart(IHeadsetClock clock)
        {
            seq = 0;
            pressId = 0;
            Clock = clock;
            Interlocked.Exchange(ref clockMinusTicks, BitConverter.DoubleToInt64Bits(double.NaN));
            Now();
        }

        void Send(byte[] data)
        {
            lock (sendLock) up.Send(data, data.Length, uplink);
        }

        void ReceiveLoop()
        {
            var from = new IPEndPoint(IPAddress.Any, 0);
            while (!stopping)
            {
                byte[] data;
                try { data = down.Receive(ref from); }
                catch (SocketException) { continue; }      // the receive timeout
                catch (ObjectDisposedException) { return; }
                double t2 = TickSeconds();
                try { Handle(data, from, t2); }
                catch (Exception e) when (!(e is ObjectDisposedException)) { Drop("internal"); }   // the thread must survive anything
            }
        }

        void Handle(byte[] data, IPEndPoint from, double t2Ticks)
        {
            if (!from.Address.Equals(pc) && !(from.Address.IsIPv4MappedToIPv6 && from.Address.MapToIPv4().Equals(pc)))
            {
                Drop("sender");
                return;
            }
            DownlinkMessage m;
            try { m = DisplayWire.Decode(data, data.Length); }
            catch (WireError e) { Drop(e.Reason); return; }
            if (m.Kind == "clock_ping")
            {
                double offset = BitConverter.Int64BitsToDouble(Interlocked.Read(ref clockMinusTicks));
                if (double.IsNaN(offset)) { Drop("clock_unset"); return; }
                byte[] echo = GazeWire.EncodeEcho(m.PingSeq, m.T1Text, t2Ticks + offset, TickSeconds() + offset);
                Send(echo);
                Interlocked.Increment(ref echoes);
            }
            else
            {
                Interlocked.Increment(ref displayReceived);
                Display.Enqueue(m);
            }
            Queue(new KeyValuePair<DownlinkMessage, string>(m, null));
        }

        void Queue(KeyValuePair<DownlinkMessage, string> item)
        {
            if (arrived.Count >= MaxQueued) { Interlocked.Increment(ref overflow); return; }
            arrived.Enqueue(item);
        }

        void Drop(string reason)
        {
            Interlocked.Increment(ref dropped);
            lock (DroppedBy)
            {
                int n;
                DroppedBy.TryGetValue(reason, out n);
                DroppedBy[reason] = n + 1;
            }
            Queue(new KeyValuePair<DownlinkMessage, string>(null, reason));
        }

        public void Dispose()
        {
            stopping = true;
            down.Close();
            if (thread != null) thread.Join(1000);
            up.Close();
        }
    }
}
