// The headset's two UDP channels (docs/headset_wire_format.md): gaze and clock echoes up to
// gaze_bridge, display messages and clock pings down from the PC. A ping is answered on the
// receive thread at once, so the echo's t2..t3 holds no frame time; display messages go to
// DisplayState for the drawing thread. Only the configured PC address is listened to.
using System;
using System.Collections.Generic;
using System.Net;
using System.Net.Sockets;
using System.Threading;

namespace FabricGuidance.Headset
{
    public sealed class HeadsetLink : IDisposable
    {
        public readonly DisplayState Display = new DisplayState();
        public IHeadsetClock Clock;
        public int Sent, Skipped, Echoes, DisplayReceived, Dropped;
        public readonly Dictionary<string, int> DroppedBy = new Dictionary<string, int>();
        /// <summary>Called on the receive thread for each accepted downlink message and each drop reason (logging).</summary>
        public Action<DownlinkMessage> Received;
        public Action<string> Rejected;

        readonly IPAddress pc;
        readonly IPEndPoint uplink;
        readonly UdpClient up;
        readonly UdpClient down;
        readonly object sendLock = new object();
        Thread thread;
        volatile bool stopping;
        uint seq;

        /// <param name="pcAddress">the PC running gaze_bridge; the only downlink sender accepted</param>
        /// <param name="uplinkPort">gaze_bridge's port (5005)</param>
        /// <param name="listen">where display messages arrive (port 5006; port 0: any free port)</param>
        public HeadsetLink(IPAddress pcAddress, int uplinkPort, IPEndPoint listen, IHeadsetClock clock, uint firstSeq = 0)
        {
            pc = pcAddress;
            uplink = new IPEndPoint(pcAddress, uplinkPort);
            Clock = clock;
            seq = firstSeq;
            up = new UdpClient(pcAddress.AddressFamily);
            down = new UdpClient(listen);
            down.Client.ReceiveTimeout = 200;   // lets Dispose stop the thread
        }

        public IPEndPoint ListenEndPoint { get { return (IPEndPoint)down.Client.LocalEndPoint; } }
        public uint NextSeq { get { return seq; } }
        /// <summary>The stamp of the last gaze frame sent (the headset clock at capture).</summary>
        public double LastStamp { get; private set; }

        public void Start()
        {
            thread = new Thread(ReceiveLoop) { IsBackground = true, Name = "headset downlink" };
            thread.Start();
        }

        /// <summary>Send one gaze frame stamped now; false (and counted) when it holds NaN or infinity.</summary>
        public bool SendGaze(GazeFrame frame)
        {
            double stamp = Clock.Now();
            byte[] data = GazeWire.Encode(seq, stamp, frame);
            if (data == null) { Skipped++; return false; }
            LastStamp = stamp;
            lock (sendLock) up.Send(data, data.Length, uplink);
            seq++;   // uint: wraps to 0 after 4294967295, as the format says
            Sent++;
            return true;
        }

        /// <summary>The app started again: seq from 0 and, with it, a new clock.</summary>
        public void Restart(IHeadsetClock clock)
        {
            seq = 0;
            Clock = clock;
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
                double t2 = Clock.Now();
                if (!from.Address.Equals(pc) && !(from.Address.IsIPv4MappedToIPv6 && from.Address.MapToIPv4().Equals(pc)))
                {
                    Drop("sender");
                    continue;
                }
                DownlinkMessage m;
                try { m = DisplayWire.Decode(data, data.Length); }
                catch (WireError e) { Drop(e.Reason); continue; }
                if (m.Kind == "clock_ping")
                {
                    byte[] echo = GazeWire.EncodeEcho(m.PingSeq, m.T1Text, t2, Clock.Now());
                    lock (sendLock) up.Send(echo, echo.Length, uplink);
                    Echoes++;
                }
                else
                {
                    DisplayReceived++;
                    Display.Enqueue(m);
                }
                var received = Received;
                if (received != null) received(m);
            }
        }

        void Drop(string reason)
        {
            Dropped++;
            lock (DroppedBy)
            {
                int n;
                DroppedBy.TryGetValue(reason, out n);
                DroppedBy[reason] = n + 1;
            }
            var rejected = Rejected;
            if (rejected != null) rejected(reason);
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
