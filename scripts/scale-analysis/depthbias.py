import sys, math, collections, statistics as st
sys.path.insert(0,__import__('os').path.dirname(__file__)); from png16 import read_png16
seq,out,folder=sys.argv[1],sys.argv[2],sys.argv[3]
S=[1.2**i for i in range(8)]
obs=[]
for l in open(f'{out}/mapdump.txt'):
    f=l.split()
    if f[0]=='O' and float(f[5])>0: obs.append(('%.6f'%float(f[1]),float(f[2]),float(f[3]),int(f[4]),float(f[5])))
# dedupe observations (same kf obs may appear once per point anyway)
byts=collections.defaultdict(list)
for o in obs: byts[o[0]].append(o)
cache={}
def D(img,w,h,x,y):
    xi=min(max(int(x),0),w-1); yi=min(max(int(y),0),h-1); return img[yi*w+xi]/5000
def bil(img,w,h,x,y):
    x0=int(math.floor(x)); y0=int(math.floor(y)); fx=x-x0; fy=y-y0
    v=[]
    for dy in (0,1):
        for dx in (0,1):
            xx=min(max(x0+dx,0),w-1); yy=min(max(y0+dy,0),h-1); v.append(img[yy*w+xx]/5000)
    if min(v)<=0: return None
    if max(v)/min(v)>1.05: return None   # discontinuity
    return (v[0]*(1-fx)+v[1]*fx)*(1-fy)+(v[2]*(1-fx)+v[3]*fx)*fy
R=collections.defaultdict(lambda: collections.defaultdict(list))
for ts,lst in byts.items():
    w,h,img=read_png16(f'{seq}/{folder}/{ts}.png')
    for t,u,v,o,d in lst:
        s=S[o]; uc=u+0.5*(s-1); vc=v+0.5*(s-1)
        ref=bil(img,w,h,uc,vc)
        if ref is None:
            R[o]['disc'].append(1); continue
        R[o]['trunc_kp'].append(d/ref)             # current: floor(u), floor(v)
        R[o]['round_kp'].append(D(img,w,h,round(u),round(v))/ref)
        R[o]['round_centre'].append(D(img,w,h,round(uc),round(vc))/ref)
        R[o]['trunc_centre'].append(D(img,w,h,uc,vc)/ref)
        R[o]['bil_kp'].append(bil(img,w,h,u,v) or ref)
        R[o]['bil_kp'][-1]/=ref
keys=['trunc_kp','round_kp','trunc_centre','round_centre','bil_kp']
print('mean (sample / bilinear depth at pixel-centre-mapped keypoint), smooth surfaces only')
print('oct   n     disc  '+'  '.join('%12s'%k for k in keys))
tot=collections.defaultdict(list)
for o in sorted(R):
    n=len(R[o]['trunc_kp'])
    print('%d  %6d  %5d  '%(o,n,len(R[o]['disc']))+'  '.join('%12.5f'%st.mean(R[o][k]) for k in keys))
    for k in keys: tot[k]+=R[o][k]
print('all %6d         '%len(tot['trunc_kp'])+'  '.join('%12.5f'%st.mean(tot[k]) for k in keys))
